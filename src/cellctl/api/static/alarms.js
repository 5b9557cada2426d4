/* cellctl dashboard: the alarms. The banner (first-out reason, acknowledge all) and the current
   alarms on the overview show on every refresh; the alarms page adds the history with its filter. */

import { getJSON, post } from "./api.js";
import { $, el, setClass, showMessage } from "./dom.js";
import { clock, dateTime } from "./format.js";
import { currentPage, model } from "./state.js";
import { refreshStatus } from "./status.js";

export async function refreshAlarms() {
  model.alarms = await getJSON("/alarms");
  renderAlarms();
  if (currentPage().page === "alarms") await refreshAlarmHistory();
}

export async function refreshAlarmHistory() {
  const data = await getJSON("/alarms?history=true");
  model.alarmHistory = data.history || [];
  renderAlarmHistory();
}

function alarmTable(alarms, { withAck, firstOutUid, compact = false }) {
  if (!alarms.length) return el("p", { class: "muted", text: "No alarms." });
  const rows = alarms.map((a) => {
    const sevCell = el("td", { text: a.severity });
    const unacked = !a.acknowledged;
    setClass(sevCell, "is-alarm", unacked && a.severity !== "warning");
    setClass(sevCell, "is-warn", unacked && a.severity === "warning");
    const when = compact ? clock : dateTime; // the pages' tables (the history goes back days) carry the date
    const state = [a.active ? "active" : "gone", a.acknowledged ? `ack by ${a.ack_by} ${when(a.ack_at)}` : "unacknowledged"].join(", ");
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
        el("td", { class: "msg" }, a.message, el("br"), el("span", { class: "muted", text: `${source}; ${state}` })),
        withAck ? el("td", {}, action) : null,
      );
    }
    return el(
      "tr",
      { "data-alarm": a.uid },
      el("td", { class: "when", text: dateTime(a.raised_at) }),
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
  // What the alarm is, first: the first-out (the one that stopped the cell), else the oldest one
  // still waiting for acknowledgement, else the oldest one.
  const lead = stop || unacked[0] || current[0] || null;
  $("first-out").textContent = lead ? `${stop ? "First-out" : "Alarm"}: ${lead.code} ${lead.message}` : "";
  $("first-out-when").textContent = lead ? `${clock(lead.raised_at)}${lead.cycle_id ? `, cycle ${lead.cycle_id}` : ""}, ${lead.source}` : "";
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

export function bindAlarms() {
  $("ack-all").addEventListener("click", acknowledgeAll);
  $("alarm-filter").addEventListener("input", renderAlarmHistory);
  $("alarm-filters").addEventListener("submit", (e) => e.preventDefault());
}
