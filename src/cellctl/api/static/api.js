/* cellctl dashboard: talking to the cell controller. Reads are GETs, commands POSTs; both carry
   the operator token when one was entered (the page keeps it in sessionStorage, this browser tab
   only), so the page also works with [api] open_reads = false. Live changes come as server-sent
   events from /events, read with fetch (an EventSource cannot send the token). */

import { $, showMessage } from "./dom.js";

const TOKEN_KEY = "cellctl.operatorToken";
// The event kinds the page listens to on /events (the commissioning page's among them).
const EVENT_KINDS = ["status", "state", "step", "cycle", "alarm", "image", "plc", "job", "job_image", "prompt"];

async function detailOf(response) {
  try {
    const body = await response.json();
    return typeof body.detail === "string" ? body.detail : JSON.stringify(body.detail ?? body);
  } catch (_) {
    return response.statusText;
  }
}

let readsRefused = false; // the newest read was answered 401: the cell wants a (valid) token, it is not gone

// Whether the cell refuses this page's reads for want of a token ([api] open_reads = false).
export function readsNeedToken() {
  return readsRefused;
}

export async function getJSON(url) {
  const r = await fetch(url, { headers: withToken({ Accept: "application/json" }), cache: "no-store" });
  readsRefused = r.status === 401;
  if (!r.ok) throw new Error(`${url}: ${r.status} ${await detailOf(r)}`);
  return r.json();
}

// An image (or any file) read with the token, as a Blob; throws like getJSON.
export async function getBlob(url) {
  const r = await fetch(url, { headers: withToken({ Accept: "image/png" }) });
  readsRefused = r.status === 401;
  if (!r.ok) throw new Error(`${url}: ${r.status} ${await detailOf(r)}`);
  return r.blob();
}

// Request headers with the operator token, if one was entered.
function withToken(headers) {
  const t = token();
  return t ? { ...headers, Authorization: `Bearer ${t}` } : headers;
}

const asked = new Map(); // slot -> number of the newest request

// getJSON for a view that refreshes itself: answers null when a newer request for the same `slot`
// began meanwhile, so an older answer arriving late never overwrites a newer one.
export async function getLatest(slot, url) {
  const n = (asked.get(slot) || 0) + 1;
  asked.set(slot, n);
  const body = await getJSON(url);
  return asked.get(slot) === n ? body : null;
}

// -- the operator token ---------------------------------------------------------------------------

export function token() {
  return sessionStorage.getItem(TOKEN_KEY) || "";
}

export function saveToken(value) {
  sessionStorage.setItem(TOKEN_KEY, value);
}

export function forgetToken() {
  sessionStorage.removeItem(TOKEN_KEY);
}

// POST with the operator token; `body` (optional) goes as JSON. `open`: a read that is a POST
// (e.g. a dry-run plan), sent with the token if there is one. Says what went wrong on the message
// line and returns null; else the answer's JSON.
export async function post(url, what, body, { open = false } = {}) {
  const t = token();
  if (!t && !open) {
    showMessage(`${what}: enter the operator token first (field "Operator token", then "Use token").`, true);
    $("token").focus();
    return null;
  }
  const init = { method: "POST", headers: { Accept: "application/json" } };
  if (t) init.headers.Authorization = `Bearer ${t}`;
  if (body !== undefined) {
    init.headers["Content-Type"] = "application/json";
    init.body = JSON.stringify(body);
  }
  let r;
  try {
    r = await fetch(url, init);
  } catch (err) {
    showMessage(`${what}: the cell controller did not answer (${err.message}).`, true);
    return null;
  }
  if (r.status === 401) {
    showMessage(`${what}: the token was refused; enter a valid operator token.`, true);
    return null;
  }
  if (!r.ok) {
    showMessage(`${what} refused (${r.status}): ${await detailOf(r)}`, true);
    return null;
  }
  return r.json();
}

// A cycle image scaled down by the dashboard's thumbnail route.
export function thumbUrl(cycleId, name, width) {
  return `/dashboard/thumbs/${cycleId}/${encodeURIComponent(name)}?width=${width}`;
}

// -- the event stream -----------------------------------------------------------------------------

const EVENTS_RETRY_MS = 2000; // after a failed or ended stream, as an EventSource would reconnect

// Opens /events: onEvent(kind, data) for each event the page listens to, onError() when the
// connection fails or ends; it reconnects by itself (with the token of that moment). The events sent
// while it was down are gone (nothing replays them): onReconnect() comes before the first event of a
// connection that follows a failed or ended one, for the page to read everything again. Returns { close() }.
export function openEvents(onEvent, onError, onReconnect = () => {}) {
  const stream = { closed: false, abort: null, dropped: false };
  const dispatch = (kind, text) => {
    if (!EVENT_KINDS.includes(kind)) return;
    let data;
    try {
      data = JSON.parse(text);
    } catch (err) {
      console.warn(`bad ${kind} event`, err);
      return;
    }
    if (stream.dropped) {
      stream.dropped = false;
      onReconnect();
    }
    onEvent(kind, data);
  };
  const connect = async () => {
    stream.abort = new AbortController();
    try {
      const init = { headers: withToken({ Accept: "text/event-stream" }), cache: "no-store", signal: stream.abort.signal };
      const r = await fetch("/events", init);
      readsRefused = r.status === 401;
      if (r.ok && r.body) await readEvents(r.body, dispatch);
    } catch (_) {
      // a failed connection is reported below, as one that ended
    }
    if (stream.closed) return;
    stream.dropped = true;
    onError();
    setTimeout(() => stream.closed || connect(), EVENTS_RETRY_MS);
  };
  connect();
  return {
    close() {
      stream.closed = true;
      if (stream.abort) stream.abort.abort();
    },
  };
}

// Reads a server-sent event stream to its end: dispatch(kind, data) for each event (a blank line ends one).
async function readEvents(body, dispatch) {
  const reader = body.pipeThrough(new TextDecoderStream()).getReader();
  let buffer = "";
  let kind = "message";
  let data = [];
  for (;;) {
    const { value, done } = await reader.read();
    if (done) return;
    buffer += value;
    let end;
    while ((end = buffer.indexOf("\n")) >= 0) {
      const line = buffer.slice(0, end).replace(/\r$/, "");
      buffer = buffer.slice(end + 1);
      if (line === "") {
        if (data.length) dispatch(kind, data.join("\n"));
        kind = "message";
        data = [];
      } else if (line.startsWith("event:")) kind = line.slice(6).trim();
      else if (line.startsWith("data:")) data.push(line.slice(5).replace(/^ /, ""));
    }
  }
}
