/* cellctl operator dashboard. Plain JavaScript, no libraries, nothing loaded from outside the
   cell controller. Data: the REST API for snapshots, /events (server-sent events) for live
   changes; the server sends a status snapshot every few seconds, so silence means stale data. */
"use strict";

(() => {
  const TOKEN_KEY = "cellctl.operatorToken";
  const PAGES = ["overview", "cycles", "alarms", "calibration", "commissioning"];
  const EVENT_KINDS = ["status", "state", "step", "cycle", "alarm", "image", "plc", "job", "job_image", "prompt"];
  const AXES = [
    { key: "dx_mm", label: "dX", unit: "mm", kind: "position" },
    { key: "dy_mm", label: "dY", unit: "mm", kind: "position" },
    { key: "dz_mm", label: "dZ", unit: "mm", kind: "position" },
    { key: "drx_deg", label: "dRx", unit: "deg", kind: "orientation" },
    { key: "dry_deg", label: "dRy", unit: "deg", kind: "orientation" },
    { key: "drz_deg", label: "dRz", unit: "deg", kind: "orientation" },
  ];
  const ALARM_STATES = new Set(["ABORTING", "ABORTED"]);
  const WARN_STATES = new Set(["HOLDING", "HELD", "SUSPENDING", "SUSPENDED"]);
  const NOK_CYCLES = new Set(["failed", "interrupted"]);
  const TREND_CYCLES = 30;
  const FILM_RECENT = 10;
  const FILM_PINNED = 6;
  const DEFAULT_CONFIG = {
    tolerance: { position_mm: 0.5, orientation_deg: 1.0 },
    simulation: false,
    mode_change_states: [],
    status_period_s: 2,
    stale_after_s: 5,
    plc_enabled: false,
    plc_heartbeat_alarm: true,
  };

  const model = {
    config: DEFAULT_CONFIG,
    status: null,
    alarms: { current: [], stop_reason: null },
    alarmHistory: null,
    digest: [],
    cycles: [],
    calibration: null,
    plc: null,
    currentCycle: null,
    liveImage: null,
    detailId: null,
    lastMessageAt: 0,
    stale: true,
    source: null,
  };

  // -- small helpers ---------------------------------------------------------------------------

  const $ = (id) => document.getElementById(id);

  function el(tag, attrs, ...children) {
    const node = document.createElement(tag);
    setAttrs(node, attrs);
    for (const c of children.flat(Infinity)) {
      if (c === null || c === undefined || c === false) continue;
      node.append(c instanceof Node ? c : String(c));
    }
    return node;
  }

  const SVG_NS = "http://www.w3.org/2000/svg";
  function svg(tag, attrs, ...children) {
    const node = document.createElementNS(SVG_NS, tag);
    setAttrs(node, attrs);
    for (const c of children.flat(Infinity)) {
      if (c === null || c === undefined || c === false) continue;
      node.append(c instanceof Node ? c : String(c));
    }
    return node;
  }

  function setAttrs(node, attrs) {
    for (const [k, v] of Object.entries(attrs || {})) {
      if (v === null || v === undefined || v === false) continue;
      if (k === "class") node.setAttribute("class", v);
      else if (k === "text") node.textContent = v;
      else if (k.startsWith("on") && typeof v === "function") node.addEventListener(k.slice(2), v);
      else node.setAttribute(k, v === true ? "" : String(v));
    }
  }

  function isNum(v) {
    return typeof v === "number" && Number.isFinite(v);
  }

  function num(v, digits = 3) {
    return isNum(v) ? v.toFixed(digits) : "-";
  }

  function signed(v, digits = 3) {
    return isNum(v) ? (v >= 0 ? "+" : "") + v.toFixed(digits) : "-";
  }

  function figure(v) {
    if (Number.isInteger(v)) return String(v);
    if (!isNum(v)) return String(v);
    const a = Math.abs(v);
    if (a !== 0 && (a < 1e-3 || a >= 1e6)) return v.toExponential(3);
    return String(Number(v.toPrecision(6)));
  }

  function clock(iso) {
    if (!iso) return "-";
    const d = new Date(iso);
    return Number.isNaN(d.getTime()) ? iso : d.toLocaleTimeString([], { hour12: false });
  }

  function dateTime(iso) {
    if (!iso) return "-";
    const d = new Date(iso);
    if (Number.isNaN(d.getTime())) return iso;
    const pad = (n) => String(n).padStart(2, "0");
    return `${d.getFullYear()}-${pad(d.getMonth() + 1)}-${pad(d.getDate())} ${d.toLocaleTimeString([], { hour12: false })}`;
  }

  function setClass(node, cls, on) {
    node.classList.toggle(cls, Boolean(on));
  }

  function flatten(value, prefix = "", out = []) {
    if (value === null || value === undefined) {
      out.push([prefix, "-"]);
    } else if (Array.isArray(value)) {
      const scalar = (v) => v === null || ["number", "string", "boolean"].includes(typeof v);
      if (value.length === 0) {
        out.push([prefix, "none"]);
      } else if (value.every((v) => typeof v === "number")) {
        out.push([prefix, "[" + value.map(figure).join(", ") + "]"]);
      } else if (value.every((v) => Array.isArray(v) && v.every((x) => typeof x === "number"))) {
        out.push([prefix, "[" + value.map((r) => "[" + r.map(figure).join(", ") + "]").join(", ") + "]"]);
      } else if (value.every((v) => v && typeof v === "object" && !Array.isArray(v) && Object.values(v).every(scalar))) {
        // A list of small records (e.g. the laser spots): one line each.
        value.forEach((v, i) => {
          const line = Object.entries(v).map(([k, x]) => `${k} ${typeof x === "number" ? figure(x) : String(x)}`);
          out.push([`${prefix}[${i}]`, line.join(", ")]);
        });
      } else {
        value.forEach((v, i) => flatten(v, `${prefix}[${i}]`, out));
      }
    } else if (typeof value === "object") {
      const keys = Object.keys(value);
      if (keys.length === 0) out.push([prefix, "-"]);
      for (const k of keys) flatten(value[k], prefix ? `${prefix}.${k}` : k, out);
    } else if (typeof value === "number") {
      out.push([prefix, figure(value)]);
    } else {
      out.push([prefix, String(value)]);
    }
    return out;
  }

  function kvList(obj) {
    const rows = flatten(obj);
    return el("dl", { class: "kv" }, rows.map(([k, v]) => [el("dt", { text: k || "value" }), el("dd", { text: v })]));
  }

  // -- the API ---------------------------------------------------------------------------------

  async function detailOf(response) {
    try {
      const body = await response.json();
      return typeof body.detail === "string" ? body.detail : JSON.stringify(body.detail ?? body);
    } catch (_) {
      return response.statusText;
    }
  }

  async function getJSON(url) {
    const r = await fetch(url, { headers: { Accept: "application/json" }, cache: "no-store" });
    if (!r.ok) throw new Error(`${url}: ${r.status} ${await detailOf(r)}`);
    return r.json();
  }

  function token() {
    return sessionStorage.getItem(TOKEN_KEY) || "";
  }

  // POST with the operator token; `body` (optional) goes as JSON. `open`: a read that is a POST
  // (e.g. a dry-run plan), sent with the token if there is one.
  async function post(url, what, body, { open = false } = {}) {
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

  function showMessage(text, isError = false) {
    const m = $("message");
    m.textContent = text;
    setClass(m, "is-alarm", isError);
  }

  // Coalesce bursts of events into one fetch per kind.
  const pending = new Map();
  function schedule(name, fn, delayMs = 100) {
    if (pending.has(name)) return;
    pending.set(
      name,
      setTimeout(async () => {
        pending.delete(name);
        try {
          await fn();
        } catch (err) {
          console.warn(`refresh ${name} failed:`, err);
        }
      }, delayMs),
    );
  }

  // The newer of the PLC link report in a status and the last "plc" event.
  function takePlcLink(status) {
    const p = status && status.links ? status.links.plc : null;
    if (p && (!model.plc || (p.since_utc || "") >= (model.plc.since_utc || ""))) model.plc = p;
  }

  async function refreshStatus() {
    model.status = await getJSON("/status");
    takePlcLink(model.status);
    await refreshCurrentCycle();
    renderStatus();
  }

  async function refreshCurrentCycle() {
    const id = model.status ? model.status.current_cycle : null;
    if (id === null || id === undefined) {
      model.currentCycle = null;
    } else if (!model.currentCycle || model.currentCycle.id !== id) {
      model.currentCycle = await getJSON(`/cycles/${id}`);
    }
  }

  async function refreshAlarms() {
    model.alarms = await getJSON("/alarms");
    renderAlarms();
    if (currentPage().page === "alarms") await refreshAlarmHistory();
  }

  async function refreshAlarmHistory() {
    const data = await getJSON("/alarms?history=true");
    model.alarmHistory = data.history || [];
    renderAlarmHistory();
  }

  async function refreshDigest() {
    model.digest = await getJSON("/dashboard/cycles?limit=60");
    renderTrends();
    renderFilmstrip();
    renderLastImage();
    renderPart();
  }

  async function refreshCycleTable() {
    const state = $("filter-state").value;
    const url = "/cycles?limit=200" + (state ? `&state=${encodeURIComponent(state)}` : "");
    model.cycles = await getJSON(url);
    renderCycleTable();
  }

  async function refreshCalibration() {
    model.calibration = await getJSON("/calibration");
    renderCalibration();
    if (model.status) renderCalibrationTile();
    emit("calibration", model.calibration);
  }

  async function refreshDetail() {
    if (model.detailId === null) return;
    const id = model.detailId;
    try {
      const record = await getJSON(`/cycles/${id}`);
      if (model.detailId === id) renderDetail(record);
    } catch (err) {
      if (model.detailId === id) $("cycle-detail").replaceChildren(el("p", { class: "is-warn problems", text: err.message }));
    }
  }

  async function refreshAll() {
    const jobs = [refreshStatus(), refreshAlarms(), refreshDigest(), refreshCalibration()];
    const page = currentPage();
    if (page.page === "cycles") jobs.push(refreshCycleTable(), refreshDetail());
    jobs.push(...emit("refresh", page));
    const results = await Promise.allSettled(jobs);
    for (const r of results) if (r.status === "rejected") console.warn("refresh failed:", r.reason);
  }

  // -- header, commands ------------------------------------------------------------------------

  function renderStatus() {
    const st = model.status;
    if (!st) return;
    $("state").textContent = st.state;
    setClass($("tile-state"), "is-alarm", ALARM_STATES.has(st.state));
    setClass($("tile-state"), "is-warn", WARN_STATES.has(st.state));
    $("mode").textContent = st.mode;
    const step = st.cycle_step && st.cycle_step !== "none" ? st.cycle_step : "none";
    $("step").textContent = st.current_cycle ? `${step} (cycle ${st.current_cycle})` : step;
    renderPart();
    renderDevices();
    renderCalibrationTile();
    renderCommands();
  }

  function renderPart() {
    const st = model.status;
    const node = $("part");
    let rec = null;
    let prefix = "";
    if (st && st.current_cycle && model.currentCycle && model.currentCycle.id === st.current_cycle) {
      rec = model.currentCycle;
    } else if (model.digest.length) {
      rec = model.digest[0];
      prefix = "last: ";
    }
    node.textContent = rec ? `${prefix}${rec.part_id} / ${rec.car_id || "-"}` : "-";
  }

  function renderDevices() {
    const st = model.status;
    const list = $("devices");
    const items = [];
    for (const [name, d] of Object.entries(st.devices || {})) {
      const age = isNum(d.heartbeat_age_s) ? `${d.heartbeat_age_s.toFixed(1)} s` : "no answer yet";
      const li = el("li", { "data-device": name }, el("span", { class: "name", text: name }), ` ${d.link} ${age}`);
      setClass(li, "is-alarm", d.link === "lost");
      setClass(li, "is-warn", d.link === "degraded" || d.link === "unknown");
      items.push(li);
    }
    if (model.config.plc_enabled) {
      // The PLC link comes with every status (links.plc) and as an event when it changes; a
      // lost heartbeat is an abnormal state only where the configuration supervises it.
      const p = model.plc;
      const supervised = model.config.plc_heartbeat_alarm;
      let text = "no report yet";
      if (p && p.link === "lost") text = `silent since ${clock(p.since_utc)}${supervised ? "" : " (not supervised)"}`;
      else if (p && p.link === "waiting") text = "waiting for its first heartbeat";
      else if (p) text = `${p.link} since ${clock(p.since_utc)}`;
      const li = el("li", { "data-device": "plc" }, el("span", { class: "name", text: "PLC" }), ` ${text}`);
      setClass(li, "is-alarm", p && p.link === "lost" && supervised);
      items.push(li);
    }
    list.replaceChildren(...items);
  }

  function renderCalibrationTile() {
    const problems = (model.status && model.status.calibration && model.status.calibration.problems) || [];
    const tile = $("tile-cal");
    const current = model.calibration && model.calibration.current;
    const version = current && current.version !== undefined && current.version !== null ? `, set v${current.version}` : "";
    $("cal").textContent = problems.length ? `NOT READY (${problems.length})` : `ready${version}`;
    tile.title = problems.length ? problems.join("\n") : "The calibration set is complete, valid and in date.";
    setClass(tile, "is-warn", problems.length > 0);
  }

  function renderCommands() {
    const st = model.status;
    const allowed = new Set(st.allowed_commands || []);
    const blocked = st.blocked_commands || {};
    const notes = [];
    for (const btn of document.querySelectorAll("[data-command]")) {
      const cmd = btn.dataset.command;
      const ok = allowed.has(cmd);
      btn.disabled = !ok;
      if (ok) {
        btn.title = `Send ${cmd} (allowed in ${st.state})`;
      } else if (blocked[cmd]) {
        btn.title = `${cmd} is held back: ${blocked[cmd]}`;
        notes.push(`${btn.textContent}: ${blocked[cmd]}`);
      } else {
        btn.title = `${cmd} is not allowed in ${st.state}`;
      }
    }
    $("blocked").textContent = notes.length ? "Held back: " + notes.join("; ") : "";
    const modeOk = (model.config.mode_change_states || []).includes(st.state);
    const apply = $("mode-apply");
    apply.disabled = !modeOk;
    apply.title = modeOk
      ? "Change the unit mode"
      : `The unit mode changes only in ${(model.config.mode_change_states || []).join(", ")}`;
    const select = $("mode-select");
    if (document.activeElement !== select && !select.dataset.touched) select.value = st.mode.toLowerCase();
  }

  function renderLive() {
    const age = model.lastMessageAt ? (Date.now() - model.lastMessageAt) / 1000 : Infinity;
    const stale = age > model.config.stale_after_s;
    model.stale = stale;
    const tile = $("tile-live");
    const text = !model.lastMessageAt ? "no data yet" : stale ? "STALE" : "live";
    if ($("live").textContent !== text) $("live").textContent = text;
    $("live-age").textContent = stale && model.lastMessageAt ? `${Math.round(age)} s` : "";
    tile.title = model.lastMessageAt
      ? `Last message from the cell controller ${age.toFixed(1)} s ago`
      : "Waiting for the cell controller";
    setClass(tile, "is-warn", stale);
    setClass(document.body, "stale", stale);
  }

  // -- alarms ----------------------------------------------------------------------------------

  function alarmTable(alarms, { withAck, firstOutUid, compact = false }) {
    if (!alarms.length) return el("p", { class: "muted", text: "No alarms." });
    const rows = alarms.map((a) => {
      const sevCell = el("td", { text: a.severity });
      const unacked = !a.acknowledged;
      setClass(sevCell, "is-alarm", unacked && a.severity !== "warning");
      setClass(sevCell, "is-warn", unacked && a.severity === "warning");
      const state = [a.active ? "active" : "gone", a.acknowledged ? `ack by ${a.ack_by} ${clock(a.ack_at)}` : "unacknowledged"].join(", ");
      const action = withAck && unacked
        ? el("button", {
            type: "button",
            class: "btn btn-small",
            "data-ack": a.uid,
            "aria-label": `Acknowledge alarm ${a.code}: ${a.message}`,
            onclick: () => acknowledge(a),
            text: "Acknowledge",
          })
        : null;
      const codeCell = el("td", {}, String(a.code), a.uid === firstOutUid ? el("strong", { text: " first-out" }) : null);
      const source = a.source + (a.cycle_id ? `, cycle ${a.cycle_id}` : "");
      if (compact) {
        setClass(codeCell, "is-alarm", unacked && a.severity !== "warning");
        setClass(codeCell, "is-warn", unacked && a.severity === "warning");
        codeCell.append(el("br"), el("span", { text: clock(a.raised_at) }));
        return el(
          "tr",
          { "data-alarm": a.uid },
          codeCell,
          el("td", {}, a.message, el("br"), el("span", { class: "muted", text: `${source}; ${state}` })),
          withAck ? el("td", {}, action) : null,
        );
      }
      return el(
        "tr",
        { "data-alarm": a.uid },
        el("td", { text: clock(a.raised_at) }),
        codeCell,
        sevCell,
        el("td", { text: a.message }),
        el("td", { text: source }),
        el("td", { text: state }),
        withAck ? el("td", {}, action) : null,
      );
    });
    const heads = (compact ? ["Code, time", "Message"] : ["Time", "Code", "Severity", "Message", "Source", "State"]).concat(
      withAck ? ["Action"] : [],
    );
    return el(
      "table",
      { class: "data" },
      el("thead", {}, el("tr", {}, heads.map((h) => el("th", { scope: "col", text: h })))),
      el("tbody", {}, rows),
    );
  }

  function renderAlarms() {
    const { current, stop_reason: stop } = model.alarms;
    const banner = $("alarm-banner");
    const unacked = current.filter((a) => !a.acknowledged);
    const active = current.filter((a) => a.active);
    banner.hidden = current.length === 0 && !stop;
    setClass(banner, "is-acked", unacked.length === 0);
    $("alarm-count").textContent = current.length
      ? `${current.length} alarm${current.length === 1 ? "" : "s"}: ${unacked.length} unacknowledged, ${active.length} active.`
      : "No current alarms.";
    $("first-out").textContent = stop
      ? ` First-out: ${stop.code} ${stop.message} (${clock(stop.raised_at)}${stop.cycle_id ? `, cycle ${stop.cycle_id}` : ""}).`
      : "";
    $("ack-all").hidden = unacked.length === 0;
    const firstOutUid = stop ? stop.uid : null;
    $("alarms-now").replaceChildren(alarmTable(current, { withAck: true, firstOutUid, compact: true }));
    $("alarms-current").replaceChildren(alarmTable(current, { withAck: true, firstOutUid }));
  }

  function renderAlarmHistory() {
    const q = $("alarm-filter").value.trim().toLowerCase();
    const rows = (model.alarmHistory || []).filter((a) => {
      if (!q) return true;
      return [String(a.code), a.message, a.source, a.cycle_id ? String(a.cycle_id) : ""].some((s) => s.toLowerCase().includes(q));
    });
    $("alarms-history").replaceChildren(alarmTable(rows, { withAck: false, firstOutUid: null }));
  }

  async function acknowledge(alarm) {
    const done = await post(`/alarms/${encodeURIComponent(alarm.uid)}/acknowledge`, `Acknowledge ${alarm.code}`);
    if (done) {
      showMessage(`Alarm ${alarm.code} acknowledged by ${done.ack_by}.`);
      await Promise.allSettled([refreshAlarms(), refreshStatus()]);
    }
  }

  async function acknowledgeAll() {
    const done = await post("/alarms/acknowledge-all", "Acknowledge all");
    if (done) {
      showMessage(`${done.length} alarm${done.length === 1 ? "" : "s"} acknowledged.`);
      await Promise.allSettled([refreshAlarms(), refreshStatus()]);
    }
  }

  // -- trends ----------------------------------------------------------------------------------

  function chart({ title, unit, band, points, digits, emptyText, width, height }) {
    // Drawn at the size it is shown, so text sizes are screen pixels.
    const W = Math.max(200, Math.round(width || 300)), H = height || 150, L = 52, R = 10, T = 28, B = 20;
    const values = points.filter((p) => isNum(p.y));
    const box = el("div", { class: "chart" });
    const label = [];
    const root = svg("svg", { viewBox: `0 0 ${W} ${H}`, role: "img" });
    const latest = values.length ? values[values.length - 1].y : null;
    const outside = (v) => isNum(band) && Math.abs(v) > band;
    root.append(svg("text", { x: 6, y: 19, class: "chart-title", text: `${title} [${unit}]` }));
    if (isNum(latest)) {
      root.append(
        svg("text", { x: W - R, y: 19, "text-anchor": "end", class: "chart-value" + (outside(latest) ? " out" : ""), text: isNum(band) ? signed(latest, digits) : num(latest, digits) }),
      );
    }
    if (!values.length) {
      root.append(svg("text", { x: W / 2, y: H / 2 + 8, "text-anchor": "middle", class: "empty", text: emptyText || "no cycles yet" }));
      root.setAttribute("aria-label", `${title}: ${emptyText || "no cycles yet"}`);
      box.append(root);
      return box;
    }
    const peak = Math.max(...values.map((p) => Math.abs(p.y)));
    let lo, hi;
    if (isNum(band)) {
      hi = Math.max(band * 1.3, peak * 1.1);
      lo = -hi;
    } else {
      lo = 0;
      hi = Math.max(peak * 1.15, 1e-9);
    }
    const n = points.length;
    const xAt = (i) => L + (n === 1 ? (W - L - R) / 2 : (i * (W - L - R)) / (n - 1));
    const yAt = (v) => T + ((hi - v) * (H - T - B)) / (hi - lo);
    if (isNum(band)) {
      root.append(svg("rect", { class: "band", x: L, y: yAt(band), width: W - L - R, height: yAt(-band) - yAt(band) }));
      for (const v of [band, -band]) {
        root.append(svg("line", { class: "tol", x1: L, x2: W - R, y1: yAt(v), y2: yAt(v) }));
        root.append(svg("text", { class: "tick", x: L - 4, y: yAt(v) + 4, "text-anchor": "end", text: signed(v, band < 1 ? 2 : 1) }));
      }
      root.append(svg("line", { class: "axis", x1: L, x2: W - R, y1: yAt(0), y2: yAt(0) }));
      root.append(svg("text", { class: "tick", x: L - 4, y: yAt(0) + 4, "text-anchor": "end", text: "0" }));
    } else {
      root.append(svg("line", { class: "axis", x1: L, x2: W - R, y1: yAt(0), y2: yAt(0) }));
      root.append(svg("text", { class: "tick", x: L - 4, y: yAt(0) + 4, "text-anchor": "end", text: "0" }));
      root.append(svg("text", { class: "tick", x: L - 4, y: yAt(peak) + 4, "text-anchor": "end", text: num(peak, 1) }));
      root.append(svg("line", { class: "tol", x1: L, x2: W - R, y1: yAt(peak), y2: yAt(peak) }));
    }
    const path = [];
    points.forEach((p, i) => {
      if (isNum(p.y)) path.push(`${xAt(i).toFixed(1)},${yAt(p.y).toFixed(1)}`);
    });
    root.append(svg("polyline", { class: "series", points: path.join(" ") }));
    let outCount = 0;
    points.forEach((p, i) => {
      if (!isNum(p.y)) return;
      const out = outside(p.y);
      if (out) outCount += 1;
      const cls = "pt" + (out ? " out" : "") + (p.nok ? " nok" : "");
      root.append(
        svg("circle", { class: cls, cx: xAt(i), cy: yAt(p.y), r: out ? 4.5 : 3 }, svg("title", { text: `cycle ${p.id}: ${signed(p.y, digits)} ${unit}` })),
      );
    });
    if (n === 1) {
      root.append(svg("text", { class: "tick", x: xAt(0), y: H - 3, "text-anchor": "middle", text: `cycle ${points[0].id}` }));
    } else {
      root.append(svg("text", { class: "tick", x: L, y: H - 3, text: `cycle ${points[0].id}` }));
      root.append(svg("text", { class: "tick", x: W - R, y: H - 3, "text-anchor": "end", text: `cycle ${points[n - 1].id}` }));
    }
    label.push(`${title}: ${values.length} cycles, latest ${signed(latest, digits)} ${unit}, largest magnitude ${num(peak, digits)} ${unit}`);
    if (isNum(band)) label.push(`${outCount} outside plus or minus ${band} ${unit}`);
    root.setAttribute("aria-label", label.join(", "));
    box.dataset.outside = String(outCount);
    box.dataset.points = String(values.length);
    box.append(root);
    return box;
  }

  function chartWidth(container, columns) {
    const gap = 6;
    const w = container.clientWidth || 900;
    return Math.floor((w - gap * (columns - 1)) / columns) - 2;
  }

  function renderTrends() {
    const tol = model.config.tolerance;
    const sixWidth = chartWidth($("trend-charts"), 3);
    const chronological = model.digest.slice().reverse();
    const useTruth = model.config.simulation || chronological.some((c) => c.true_error);
    const installed = chronological.filter((c) => c.state === "done").slice(-TREND_CYCLES);
    const source = useTruth ? "true_error" : "residual";
    $("h-trends").textContent = useTruth ? "Install deviation: true error (simulated cell)" : "Install deviation: verification shot residual";
    $("trend-note").textContent =
      (useTruth
        ? "The twin's truth of the installed glass against the template, "
        : "The last verification shot's offset; dZ, dRx and dRy are set by the laser alignment and not measured by the shot. ") +
      (installed.length ? `last ${installed.length} installed cycle${installed.length === 1 ? "" : "s"}` : "no installed cycle yet") +
      `; grey band: tolerance \u00b1${tol.position_mm} mm, \u00b1${tol.orientation_deg} deg.`;
    const charts = AXES.map((ax) => {
      const band = ax.kind === "position" ? tol.position_mm : tol.orientation_deg;
      const points = installed.map((c) => ({ id: c.id, y: c[source] ? c[source][ax.key] : null, nok: false }));
      const c = chart({
        title: ax.label,
        unit: ax.unit,
        band,
        points,
        digits: 3,
        width: sixWidth,
        height: 130,
        emptyText: useTruth || installed.length === 0 ? "no installed cycle yet" : "not measured by the verification shot",
      });
      c.dataset.axis = ax.key;
      return c;
    });
    $("trend-charts").replaceChildren(...charts);
    const timed = chronological.filter((c) => isNum(c.cycle_time_s)).slice(-TREND_CYCLES);
    const ct = chart({
      title: "Cycle time",
      unit: "s",
      band: null,
      points: timed.map((c) => ({ id: c.id, y: c.cycle_time_s, nok: c.state !== "done" })),
      digits: 2,
      emptyText: "no finished cycle yet",
      width: chartWidth($("cycle-time-chart"), 1),
      height: 110,
    });
    ct.dataset.axis = "cycle_time_s";
    $("cycle-time-chart").replaceChildren(ct);
  }

  // -- images ----------------------------------------------------------------------------------

  function thumbUrl(cycleId, name, width) {
    return `/dashboard/thumbs/${cycleId}/${encodeURIComponent(name)}?width=${width}`;
  }

  function renderLastImage() {
    let shown = model.liveImage;
    if (!shown) {
      const c = model.digest.find((d) => d.image);
      if (c) shown = { cycle_id: c.id, name: c.image.name };
    }
    const img = $("last-image");
    const link = $("last-image-link");
    img.hidden = !shown;
    if (!shown) return;
    const src = thumbUrl(shown.cycle_id, shown.name, 640);
    if (img.getAttribute("src") !== src) {
      img.src = src;
      img.alt = `Annotated camera image ${shown.name} of cycle ${shown.cycle_id}, with the vision overlay`;
      img.dataset.cycle = String(shown.cycle_id);
      link.href = `/cycles/${shown.cycle_id}/images/${encodeURIComponent(shown.name)}`;
    }
    const c = model.digest.find((d) => d.id === shown.cycle_id);
    const what = c ? `part ${c.part_id}, ${c.state}` : "running";
    $("last-image-caption").textContent = `Cycle ${shown.cycle_id}, ${shown.name}: ${what}. Select the image for full size.`;
  }

  function filmItem(c, pinned) {
    const img = c.image
      ? el("img", { src: thumbUrl(c.id, c.image.name, 240), alt: "", loading: "lazy", width: 240, height: 240 })
      : el("span", { class: "noimg", text: "no image" });
    const btn = el(
      "button",
      {
        type: "button",
        class: "film" + (pinned ? " is-pinned" : ""),
        "data-cycle": c.id,
        "aria-label": `Cycle ${c.id}, part ${c.part_id}, ${c.state}${pinned ? ", not OK, pinned" : ""}: show its detail`,
        onclick: () => {
          location.hash = `#/cycles/${c.id}`;
        },
      },
      img,
      el("span", { class: "cap" }, pinned ? el("span", { class: "pin", text: "NOT OK" }) : null, ` #${c.id} ${c.part_id}`),
      el("span", { class: "cap", text: `${c.state} ${clock(c.finished_at || c.created_at)}` }),
    );
    return el("li", {}, btn);
  }

  function renderFilmstrip() {
    const pinned = model.digest.filter((c) => NOK_CYCLES.has(c.state)).slice(0, FILM_PINNED);
    const pinnedIds = new Set(pinned.map((c) => c.id));
    const recent = model.digest.filter((c) => !pinnedIds.has(c.id)).slice(0, FILM_RECENT);
    const items = [...pinned.map((c) => filmItem(c, true)), ...recent.map((c) => filmItem(c, false))];
    $("filmstrip").replaceChildren(...(items.length ? items : [el("li", { class: "muted", text: "No cycles yet." })]));
  }

  // -- cycle history and detail ------------------------------------------------------------------

  function triple(v, digits) {
    return Array.isArray(v) && v.length === 3 ? v.map((x) => signed(x, digits)).join(" ") : "-";
  }

  function renderCycleTable() {
    const q = $("filter-part").value.trim().toLowerCase();
    const rows = model.cycles.filter((c) => !q || (c.part_id || "").toLowerCase().includes(q));
    $("cycle-count").textContent = `${rows.length} of ${model.cycles.length} loaded cycles`;
    const body = rows.map((c) => {
      const res = c.result || {};
      const stateCell = el("td", { text: c.state });
      setClass(stateCell, "is-alarm", NOK_CYCLES.has(c.state));
      const tr = el(
        "tr",
        { class: "clickable" + (model.detailId === c.id ? " is-selected" : ""), "data-cycle": c.id },
        el("td", {}, el("a", { href: `#/cycles/${c.id}`, text: `#${c.id}` })),
        stateCell,
        el("td", { text: c.part_id }),
        el("td", { text: c.car_id || "-" }),
        el("td", { text: dateTime(c.started_at || c.created_at) }),
        el("td", { class: "num", text: num(res.cycle_time_s, 2) }),
        el("td", { class: "num", text: triple(res.correction_mm, 2) }),
        el("td", { class: "num", text: triple(res.correction_deg, 3) }),
        el("td", { text: c.error || "" }),
      );
      tr.addEventListener("click", (ev) => {
        if (ev.target.tagName !== "A") location.hash = `#/cycles/${c.id}`;
      });
      return tr;
    });
    $("cycle-table").tBodies[0].replaceChildren(...body);
  }

  function renderDetail(rec) {
    const res = rec.result || {};
    const parts = [
      el("h2", { text: `Cycle ${rec.id}: ${rec.state}` }),
      rec.error ? el("p", { class: "problems is-alarm", text: rec.error }) : null,
      el(
        "dl",
        { class: "kv" },
        [
          ["Part", rec.part_id],
          ["Car", rec.car_id || "-"],
          ["Recipe", rec.recipe],
          ["Requested by", `${rec.actor} via ${rec.source}`],
          ["Created", dateTime(rec.created_at)],
          ["Started", dateTime(rec.started_at)],
          ["Finished", dateTime(rec.finished_at)],
          ["Cycle time", isNum(res.cycle_time_s) ? `${res.cycle_time_s.toFixed(2)} s` : "-"],
          ["Correction", `${triple(res.correction_mm, 3)} mm, ${triple(res.correction_deg, 4)} deg`],
          ["Interrupted in", rec.interrupted_step || "-"],
        ].map(([k, v]) => [el("dt", { text: k }), el("dd", { text: v })]),
      ),
    ];
    if (rec.true_error) {
      parts.push(el("h3", { text: "True install error (simulation)" }));
      const te = rec.true_error;
      const tol = model.config.tolerance;
      const cells = AXES.map((ax) => {
        const v = te[ax.key];
        const band = ax.kind === "position" ? tol.position_mm : tol.orientation_deg;
        const td = el("td", { class: "num", text: signed(v, 4) });
        setClass(td, "is-alarm", isNum(v) && Math.abs(v) > band);
        return td;
      });
      parts.push(
        el(
          "table",
          { class: "data" },
          el("thead", {}, el("tr", {}, AXES.map((ax) => el("th", { scope: "col", text: `${ax.label} ${ax.unit}` })))),
          el("tbody", {}, el("tr", {}, cells)),
        ),
      );
    }
    parts.push(el("h3", { text: "Images" }));
    const images = (rec.images || []).map((i) =>
      el(
        "a",
        { href: i.url, target: "_blank", rel: "noopener" },
        el("img", { src: thumbUrl(rec.id, i.name, 320), alt: `Annotated image ${i.name} of cycle ${rec.id} (${i.step})`, loading: "lazy" }),
        `${i.name} (${i.step})`,
      ),
    );
    parts.push(images.length ? el("div", { class: "thumbs" }, images) : el("p", { class: "muted", text: "No images." }));
    parts.push(el("h3", { text: "Steps" }));
    const steps = (rec.steps || []).map((s) => {
      const okCell = el("td", { text: s.ok === null ? "open" : s.ok ? "ok" : "NOT OK" });
      setClass(okCell, "is-alarm", s.ok === false);
      return el(
        "tr",
        {},
        el("td", { text: `${s.step} ${s.attempt}` }),
        el("td", { class: "num", text: num(s.duration_s, 3) }),
        okCell,
        el("td", {}, Object.keys(s.figures || {}).length ? kvList(s.figures) : "-", s.error ? el("p", { text: s.error }) : null),
      );
    });
    parts.push(
      el(
        "table",
        { class: "data steps" },
        el("thead", {}, el("tr", {}, ["Step", "Duration s", "Result", "Figures"].map((h) => el("th", { scope: "col", text: h })))),
        el("tbody", {}, steps),
      ),
    );
    $("cycle-detail").replaceChildren(...parts.filter(Boolean));
  }

  // -- calibration -----------------------------------------------------------------------------

  function calibrationCurrent(current) {
    if (!current || !Object.keys(current).length) return el("p", { class: "muted", text: "No calibration set loaded." });
    const parts = current.parts;
    if (!parts || typeof parts !== "object") return el("div", { class: "panel" }, kvList(current));
    // The versioned calibration set: one row per part with its status, date, method and quality.
    const { parts: _omit, ...rest } = current;
    const names = Object.keys(parts);
    const rows = names.map((name) => {
      const p = parts[name];
      if (!p) {
        const missing = el("td", { text: "missing" });
        setClass(missing, "is-warn", true);
        return el("tr", { "data-part": name }, el("th", { scope: "row", text: name }), missing, el("td", { text: "-" }), el("td", { text: "-" }), el("td", { text: "-" }));
      }
      const status = el("td", { text: p.status || "-" });
      setClass(status, "is-alarm", p.status === "failed");
      return el(
        "tr",
        { "data-part": name },
        el("th", { scope: "row", text: name }),
        status,
        el("td", { text: dateTime(p.calibrated_utc) }),
        el("td", { text: p.method || "-" }),
        el("td", {}, p.quality && Object.keys(p.quality).length ? kvList(p.quality) : "-", p.failure ? el("p", { text: p.failure }) : null),
      );
    });
    return el(
      "div",
      { class: "panel" },
      kvList(rest),
      names.length
        ? el(
            "table",
            { class: "data", id: "cal-parts" },
            el("thead", {}, el("tr", {}, ["Part", "Status", "Calibrated", "Method", "Quality figures"].map((h) => el("th", { scope: "col", text: h })))),
            el("tbody", {}, rows),
          )
        : el("p", { class: "muted", text: "The set has no parts yet." }),
    );
  }

  function renderCalibration() {
    const cal = model.calibration;
    if (!cal) return;
    const problems = cal.problems || [];
    $("cal-problems").replaceChildren(
      problems.length
        ? el("div", { class: "panel problems is-warn", role: "alert" }, el("strong", { text: "Not ready for production:" }), el("ul", {}, problems.map((p) => el("li", { text: p }))))
        : el("p", { class: "panel", text: "Ready for production: the set is complete, valid and in date." }),
    );
    $("cal-current").replaceChildren(calibrationCurrent(cal.current));
    $("cal-history").replaceChildren(versionsTable(cal.versions || [], cal.current ? cal.current.version : null));
  }

  // The calibration set's versions, newest first: each part's status in that version.
  function versionsTable(versions, currentVersion) {
    if (!versions.length) return el("p", { class: "muted", text: "No calibration-set version stored yet." });
    const names = [...new Set(versions.flatMap((v) => Object.keys(v.parts || {})))];
    const rows = versions.slice().reverse().map((v) => {
      const isCurrent = v.version === currentVersion;
      const cells = names.map((n) => {
        const st = (v.parts || {})[n];
        const td = el("td", { text: st || "-", "data-part": n });
        setClass(td, "is-alarm", isCurrent && st === "failed"); // colour only what is in use now
        return td;
      });
      return el(
        "tr",
        { "data-version": v.version, class: isCurrent ? "is-current" : null },
        el("th", { scope: "row" }, `v${v.version}`, isCurrent ? el("strong", { text: " (in use)" }) : null),
        el("td", { text: dateTime(v.created_utc) }),
        el("td", { text: v.note || "-" }),
        cells,
      );
    });
    return el(
      "table",
      { class: "data versions" },
      el("caption", { class: "visually-hidden", text: "Calibration-set versions, newest first" }),
      el("thead", {}, el("tr", {}, ["Version", "Created", "Note", ...names].map((h) => el("th", { scope: "col", text: h })))),
      el("tbody", {}, rows),
    );
  }

  // -- pages -----------------------------------------------------------------------------------

  function currentPage() {
    const m = /^#\/(\w+)(?:\/(\d+))?/.exec(location.hash || "");
    const page = m && PAGES.includes(m[1]) ? m[1] : "overview";
    const id = m && m[2] ? Number(m[2]) : null;
    return { page, id };
  }

  function route() {
    const { page, id } = currentPage();
    for (const p of PAGES) $(`page-${p}`).hidden = p !== page;
    for (const a of document.querySelectorAll(".tabs a")) {
      if (a.dataset.page === page) a.setAttribute("aria-current", "page");
      else a.removeAttribute("aria-current");
    }
    model.detailId = page === "cycles" ? id : null;
    if (page === "cycles") {
      schedule("cycles", refreshCycleTable, 0);
      if (id !== null) schedule("detail", refreshDetail, 0);
    }
    if (page === "alarms") schedule("alarm-history", refreshAlarmHistory, 0);
    if (page === "calibration") schedule("calibration", refreshCalibration, 0);
    emit("route", page, id);
  }

  // -- live updates ----------------------------------------------------------------------------

  function onEvent(kind, data) {
    const wasStale = model.stale && model.lastMessageAt !== 0;
    model.lastMessageAt = Date.now();
    renderLive();
    if (wasStale && kind !== "status") schedule("all", refreshAll, 0);
    switch (kind) {
      case "status":
        model.status = data;
        takePlcLink(data);
        if (wasStale) schedule("all", refreshAll, 0);
        else if ((data.current_cycle ?? null) !== (model.currentCycle ? model.currentCycle.id : null)) schedule("status", refreshStatus);
        renderStatus();
        break;
      case "state":
        if (model.status) {
          model.status.state = data.state;
          model.status.mode = data.mode;
          model.status.cycle_step = data.step;
          renderStatus();
        }
        schedule("status", refreshStatus, 50);
        break;
      case "step":
        if (model.status) {
          model.status.cycle_step = data.step;
          model.status.current_cycle = data.cycle_id;
          renderStatus();
        }
        schedule("status", refreshStatus);
        break;
      case "cycle":
        schedule("status", refreshStatus);
        schedule("digest", refreshDigest, 150);
        schedule("calibration", refreshCalibration, 300);
        if (currentPage().page === "cycles") schedule("cycles", refreshCycleTable, 150);
        if (model.detailId === data.cycle_id) schedule("detail", refreshDetail, 150);
        break;
      case "alarm":
        schedule("alarms", refreshAlarms, 50);
        schedule("status", refreshStatus, 50);
        break;
      case "image":
        model.liveImage = { cycle_id: data.cycle_id, name: data.name };
        renderLastImage();
        if (model.detailId === data.cycle_id) schedule("detail", refreshDetail, 300);
        break;
      case "plc":
        model.plc = data;
        if (model.status) renderDevices();
        break;
      default:
        break;
    }
    emit("event", kind, data);
  }

  function connect() {
    const es = new EventSource("/events");
    model.source = es;
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
    es.addEventListener("error", () => renderLive());
  }

  // -- wiring ----------------------------------------------------------------------------------

  function renderTokenState() {
    $("token-state").textContent = token() ? "Token set for this browser tab." : "No token: commands and acknowledge need one.";
    emit("token", Boolean(token()));
  }

  function bind() {
    for (const btn of document.querySelectorAll("[data-command]")) {
      btn.addEventListener("click", async () => {
        const cmd = btn.dataset.command;
        const done = await post(`/commands/${cmd}`, `Command ${cmd}`);
        if (done) {
          showMessage(`${cmd} accepted: ${done.state}, ${done.mode}.`);
          schedule("status", refreshStatus, 0);
        }
      });
    }
    $("mode-select").addEventListener("change", (e) => {
      e.target.dataset.touched = "1";
    });
    $("mode-apply").addEventListener("click", async () => {
      const mode = $("mode-select").value;
      const done = await post(`/mode/${mode}`, `Mode ${mode}`);
      delete $("mode-select").dataset.touched;
      if (done) {
        showMessage(`Mode changed: ${done.mode}.`);
        schedule("status", refreshStatus, 0);
      }
    });
    $("ack-all").addEventListener("click", acknowledgeAll);
    $("token-form").addEventListener("submit", (e) => {
      e.preventDefault();
      const value = $("token").value.trim();
      if (value) sessionStorage.setItem(TOKEN_KEY, value);
      $("token").value = "";
      renderTokenState();
      showMessage(value ? "Operator token set for this browser tab." : "Type the token into the field first.", !value);
    });
    $("token-forget").addEventListener("click", () => {
      sessionStorage.removeItem(TOKEN_KEY);
      renderTokenState();
      showMessage("Operator token forgotten.");
    });
    $("filter-state").addEventListener("change", () => schedule("cycles", refreshCycleTable, 0));
    $("filter-part").addEventListener("input", renderCycleTable);
    $("alarm-filter").addEventListener("input", renderAlarmHistory);
    $("cycle-filters").addEventListener("submit", (e) => e.preventDefault());
    $("alarm-filters").addEventListener("submit", (e) => e.preventDefault());
    window.addEventListener("hashchange", route);
    let resizeTimer = null;
    window.addEventListener("resize", () => {
      clearTimeout(resizeTimer);
      resizeTimer = setTimeout(renderTrends, 150);
    });
  }

  async function init() {
    bind();
    renderTokenState();
    try {
      model.config = Object.assign({}, DEFAULT_CONFIG, await getJSON("/dashboard/config"));
    } catch (err) {
      showMessage(`Could not read the dashboard settings (${err.message}); using defaults.`, true);
    }
    route();
    connect();
    await refreshAll();
    setInterval(renderLive, 500);
    renderLive();
    document.body.dataset.ready = "1";
  }

  // -- the namespace other page scripts (commissioning.js) use ---------------------------------

  const hooks = { event: [], route: [], token: [], calibration: [], refresh: [] };
  function emit(name, ...args) {
    const out = [];
    for (const fn of hooks[name]) {
      try {
        out.push(fn(...args));
      } catch (err) {
        console.error(`${name} hook failed:`, err);
      }
    }
    return out.filter((r) => r instanceof Promise);
  }

  window.cellctlDashboard = { model, loadedAt: Date.now() };
  window.cellctl = {
    model, $, el, kvList, isNum, num, figure, clock, dateTime, setClass, getJSON, post, token, showMessage, schedule,
    refreshCalibration, versionsTable, currentPage,
    on: (name, fn) => hooks[name].push(fn),
  };
  document.addEventListener("DOMContentLoaded", init);
})();
