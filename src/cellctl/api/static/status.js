/* cellctl dashboard: the header (PackML state, unit mode, cycle step, part, devices, calibration,
   the live/stale mark) and the command bar (PackML commands, unit mode, the operator token). The
   header shows on every page. */

import { forgetToken, getJSON, getLatest, post, saveToken, token } from "./api.js";
import { $, el, setClass, showMessage } from "./dom.js";
import { DUE_SOON_DAYS, calibrationDue, dueIn } from "./caldue.js";
import { serviceNow } from "./clock.js";
import { readiness, readinessLines, readinessWord } from "./calready.js";
import { clock, day, isNum } from "./format.js";
import { renderSpc } from "./spc.js";
import { applyStale } from "./stale.js";
import { emit, model, schedule } from "./state.js";
import { stateKind, stateMark } from "./statemark.js";

const ALARM_STATES = new Set(["ABORTING", "ABORTED"]);
const WARN_STATES = new Set(["HOLDING", "HELD", "SUSPENDING", "SUSPENDED"]);

// The newer of the PLC link report in a status and the last "plc" event.
export function takePlcLink(status) {
  const p = status && status.links ? status.links.plc : null;
  if (p && (!model.plc || (p.since_utc || "") >= (model.plc.since_utc || ""))) model.plc = p;
}

export async function refreshStatus() {
  const status = await getLatest("status", "/status");
  if (status === null) return;
  model.status = status;
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

// -- the header -----------------------------------------------------------------------------------

export function renderStatus() {
  const st = model.status;
  if (!st) return;
  $("state").textContent = st.state;
  const kind = stateKind(st.state);
  const tile = $("tile-state");
  if (tile.dataset.state !== st.state) {
    tile.dataset.state = st.state;
    $("state-mark").replaceChildren(stateMark(kind));
  }
  setClass($("tile-state"), "is-alarm", ALARM_STATES.has(st.state));
  setClass($("tile-state"), "is-warn", WARN_STATES.has(st.state));
  $("mode").textContent = st.mode;
  const step = st.cycle_step && st.cycle_step !== "none" ? st.cycle_step : "none";
  $("step").textContent = st.current_cycle ? `${step} (cycle ${st.current_cycle})` : step;
  renderPart();
  renderDevices();
  renderCalibrationTile();
  renderCommands();
  renderSpc();
}

const ENDED_CYCLES = new Set(["done", "failed", "interrupted"]);

// The part of the cycle running now, else of the newest cycle that ended (never a queued one),
// and how many cycles wait in the queue (/status queued_cycles).
export function renderPart() {
  const st = model.status;
  const node = $("part");
  let rec = null;
  let prefix = "";
  if (st && st.current_cycle && model.currentCycle && model.currentCycle.id === st.current_cycle) {
    rec = model.currentCycle;
  } else {
    rec = model.digest.find((c) => ENDED_CYCLES.has(c.state)) || null;
    prefix = "last: ";
  }
  node.textContent = rec ? `${prefix}${rec.part_id} / ${rec.car_id || "-"}` : "-";
  const queued = st && isNum(st.queued_cycles) ? st.queued_cycles : 0;
  $("part-queued").textContent = queued ? `${queued} queued` : "";
}

export function renderDevices() {
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

// The service's verdict for every recipe: the status's calibration.recipes (each with its problems),
// else GET /calibration's current.recipes (each ready or not).
export function calibrationReadiness() {
  const cal = (model.status && model.status.calibration) || {};
  const current = model.calibration && model.calibration.current;
  const recipes = cal.recipes || (current && current.recipes) || {};
  return readiness(cal.problems || [], recipes);
}

export function renderCalibrationTile() {
  const r = calibrationReadiness();
  const tile = $("tile-cal");
  const current = model.calibration && model.calibration.current;
  const version = current && current.version !== undefined && current.version !== null ? `, set v${current.version}` : "";
  $("cal").textContent = r.ready ? `ready${version}` : readinessWord(r);
  const due = calibrationDue(model.calibration, serviceNow());
  const soon = due && due.daysLeft < DUE_SOON_DAYS;
  const rel = due ? dueIn(due) : "";
  $("cal-due").textContent = due
    ? `due ${day(due.due)} (${rel.replace(/^in /, "")})`
    : current && current.parts ? "due: no valid part" : "no due date";
  tile.title =
    (r.ready ? "Every recipe is ready for production: the set is complete, valid and in date." : readinessLines(r).join("\n")) +
    (due ? `\nDue ${day(due.due)} (${rel}): ${due.part} expires first.` : "");
  setClass(tile, "is-warn", !r.ready || soon);
}

function renderCommands() {
  const st = model.status;
  const pending = !st.allowed_commands; // a state event came without its commands; /status follows
  const allowed = new Set(st.allowed_commands || []);
  const blocked = st.blocked_commands || {};
  const notes = [];
  for (const btn of document.querySelectorAll("[data-command]")) {
    const cmd = btn.dataset.command;
    const ok = allowed.has(cmd) && !model.stale;
    btn.disabled = !ok;
    if (model.stale) {
      btn.title = `${cmd}: the data is stale, so no command is sent`;
    } else if (pending) {
      btn.title = `${cmd}: reading what ${st.state} allows`;
    } else if (ok) {
      btn.title = `Send ${cmd} (allowed in ${st.state})`;
    } else if (blocked[cmd]) {
      btn.title = `${cmd} is held back: ${blocked[cmd]}`;
      notes.push(`${btn.textContent}: ${blocked[cmd]}`);
    } else {
      btn.title = `${cmd} is not allowed in ${st.state}`;
    }
  }
  $("blocked").textContent = notes.length ? "Held back: " + notes.join("; ") : "";
  const modeOk = (model.config.mode_change_states || []).includes(st.state) && !model.stale;
  const apply = $("mode-apply");
  apply.disabled = !modeOk;
  apply.title = modeOk
    ? "Change the unit mode"
    : `The unit mode changes only in ${(model.config.mode_change_states || []).join(", ")}`;
  const select = $("mode-select");
  if (document.activeElement !== select && !select.dataset.touched) select.value = st.mode.toLowerCase();
}

export function renderLive() {
  const age = model.lastMessageAt ? (performance.now() - model.lastMessageMono) / 1000 : Infinity;
  const stale = age > model.config.stale_after_s;
  const changed = stale !== model.stale;
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
  applyStale(stale, model.lastMessageAt, age);
  if (changed && model.status) renderCommands(); // the state's own rules again on recovery
}

// -- the command bar ------------------------------------------------------------------------------

export function renderTokenState() {
  $("token-state").textContent = token() ? "Token set for this browser tab." : "No token: commands and acknowledge need one.";
  emit("token", Boolean(token()));
}

export function bindControls() {
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
  $("token-form").addEventListener("submit", (e) => {
    e.preventDefault();
    const value = $("token").value.trim();
    if (value) saveToken(value);
    $("token").value = "";
    renderTokenState();
    showMessage(value ? "Operator token set for this browser tab." : "Type the token into the field first.", !value);
  });
  $("token-forget").addEventListener("click", () => {
    forgetToken();
    renderTokenState();
    showMessage("Operator token forgotten.");
  });
}
