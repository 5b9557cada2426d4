/* cellctl operator dashboard. Plain JavaScript (native ES modules), no libraries, nothing loaded
   from outside the cell controller. Data: the REST API for snapshots, /events (server-sent events)
   for live changes; the server sends a status snapshot every few seconds, so silence means stale
   data.

   This module is the entry point: it routes between the pages, refreshes them, hands each event to
   the views it concerns and starts the page. The views are modules of their own:
     status.js         the header tiles and the command bar (commands, unit mode, operator token)
     alarms.js         the alarm banner, the current alarms and the alarms page
     overview.js       the overview: last image, trend charts (chart.js), filmstrip; shifts.js
                       its shift counters
     stale.js          no control works while the data is stale (status.js decides when)
     cycles.js         the cycles page: history and cycle detail
     calibration.js    the calibration page
     commissioning.js  the commissioning page (with comm-*.js), following the rest through the
                       hooks in state.js
   under them api.js (requests, token, event stream), state.js (the model, the address, the refresh
   scheduler, the hooks), dom.js and format.js (building elements, formatting figures), figures.js
   (nested records as short, folded key-value lists), statemark.js (a shape per PackML state),
   caldue.js (when the calibration set falls due) and clock.js (the service's clock, which due times are reckoned on). */

import { getJSON, openEvents } from "./api.js";
import { bindAlarms, refreshAlarmHistory, refreshAlarms } from "./alarms.js";
import { refreshCalibration } from "./calibration.js";
import { installCommissioning } from "./commissioning.js";
import { bindCycles, refreshCycleTable, refreshDetail } from "./cycles.js";
import { $, showMessage } from "./dom.js";
import { refreshDigest, renderLastImage, renderTrends } from "./overview.js";
import { refreshShifts } from "./shifts.js";
import { DEFAULT_CONFIG, PAGES, currentPage, emit, model, on, schedule } from "./state.js";
import {
  bindControls,
  refreshStatus,
  renderDevices,
  renderLive,
  renderStatus,
  renderTokenState,
  takePlcLink,
} from "./status.js";

const SHIFT_POLL_MS = 60_000;

// -- refreshing --------------------------------------------------------------------------------

// Everything the header and the page shown need, read again (at the start; after stale data or a
// reconnect through resync).
async function refreshAll() {
  const jobs = [refreshStatus(), refreshAlarms(), refreshDigest(), refreshCalibration(), refreshShifts()];
  const page = currentPage();
  if (page.page === "cycles") jobs.push(refreshCycleTable(), refreshDetail());
  jobs.push(...emit("refresh", page));
  const results = await Promise.allSettled(jobs);
  for (const r of results) if (r.status === "rejected") console.warn("refresh failed:", r.reason);
}

// The settings and then everything else, read again: after stale data and after the event stream
// reconnected (what happened while it was down came as events that are gone; a restarted service
// may run an edited config).
async function resync() {
  await readConfig();
  await refreshAll();
}

// -- pages ----------------------------------------------------------------------------------------

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

// -- live updates ---------------------------------------------------------------------------------

// The calibration page follows the service's verdict: when the status's calibration problems or a
// recipe's readiness change (a part expired, a new version came), /calibration is read again.
let lastVerdict = null;
function calibrationVerdict(status) {
  const cal = status.calibration || {};
  const key = JSON.stringify([cal.problems || [], cal.recipes || {}]);
  if (lastVerdict !== null && key !== lastVerdict) schedule("calibration", refreshCalibration, 0);
  lastVerdict = key;
}

function onEvent(kind, data) {
  const wasStale = model.stale && model.lastMessageAt !== 0;
  model.lastMessageAt = Date.now();
  model.lastMessageMono = performance.now();
  renderLive();
  if (wasStale && kind !== "status") schedule("all", resync, 0);
  switch (kind) {
    case "status":
      model.status = data;
      takePlcLink(data);
      if (wasStale) schedule("all", resync, 0);
      else if ((data.current_cycle ?? null) !== (model.currentCycle ? model.currentCycle.id : null)) schedule("status", refreshStatus);
      renderStatus();
      calibrationVerdict(data);
      break;
    case "state":
      if (model.status) {
        const st = model.status;
        if (data.allowed_commands) {
          st.allowed_commands = data.allowed_commands;
          st.blocked_commands = data.blocked_commands || {};
        } else if (st.state !== data.state) {
          st.allowed_commands = null; // the old state's commands are not this one's: pending until read
          st.blocked_commands = {};
        }
        st.state = data.state;
        st.mode = data.mode;
        st.cycle_step = data.step;
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
      schedule("shifts", refreshShifts, 400);
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

// -- wiring ---------------------------------------------------------------------------------------

function bind() {
  bindControls();
  bindAlarms();
  bindCycles();
  window.addEventListener("hashchange", route);
  let resizeTimer = null;
  window.addEventListener("resize", () => {
    clearTimeout(resizeTimer);
    resizeTimer = setTimeout(renderTrends, 150);
  });
}

async function readConfig() {
  try {
    model.config = Object.assign({}, DEFAULT_CONFIG, await getJSON("/dashboard/config"));
  } catch (err) {
    showMessage(`Could not read the dashboard settings (${err.message}); using defaults.`, true);
  }
}

async function init() {
  installCommissioning();
  bind();
  renderTokenState();
  await readConfig();
  route();
  model.source = openEvents(onEvent, renderLive, () => schedule("all", resync, 0));
  // With [api] open_reads = false the reads before the token were refused: read everything again with it.
  on("token", (set) => set && readConfig().then(() => schedule("all", refreshAll, 0)));
  await refreshAll();
  setInterval(renderLive, 500);
  setInterval(() => schedule("shifts", refreshShifts, 0), SHIFT_POLL_MS); // a new shift begins without a cycle
  renderLive();
  document.body.dataset.ready = "1";
}

window.cellctlDashboard = { model, loadedAt: Date.now() };
document.addEventListener("DOMContentLoaded", init);
