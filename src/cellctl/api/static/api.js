/* cellctl dashboard: talking to the cell controller. Reads are plain GETs; commands are POSTs with
   the operator token, which the page keeps in sessionStorage (this browser tab only); live changes
   come as server-sent events from /events. */

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

export async function getJSON(url) {
  const r = await fetch(url, { headers: { Accept: "application/json" }, cache: "no-store" });
  if (!r.ok) throw new Error(`${url}: ${r.status} ${await detailOf(r)}`);
  return r.json();
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

// Opens /events: onEvent(kind, data) for each event the page listens to, onError() when the
// connection fails (the browser reconnects by itself).
export function openEvents(onEvent, onError) {
  const es = new EventSource("/events");
  for (const kind of EVENT_KINDS) {
    es.addEventListener(kind, (e) => {
      let data;
      try {
        data = JSON.parse(e.data);
      } catch (err) {
        console.warn(`bad ${kind} event`, err);
        return;
      }
      onEvent(kind, data);
    });
  }
  es.addEventListener("error", () => onError());
  return es;
}
