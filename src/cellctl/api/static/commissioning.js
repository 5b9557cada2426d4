/* cellctl dashboard: the commissioning page (#/commissioning, #/commissioning/7). Calibration,
   teaching and verification run in the service as jobs (POST /jobs); this page starts them, shows
   the plan of a dry run, follows the running job (progress, live camera frame, the prompt it waits
   at), answers prompts and cancels. It follows the rest of the dashboard through the hooks in
   state.js (events, routing, token, calibration); nothing here is loaded from outside the cell.

   This module holds the page's data, the job panel (renderJob) and what the buttons do; the
   panels' parts are in comm-procedures.js and comm-job.js, what the page knows in comm-state.js. */

import { getJSON, post } from "./api.js";
import { refreshCalibration, versionsTable } from "./calibration.js";
import { $, el, showMessage } from "./dom.js";
import { dateTime, isNum } from "./format.js";
import { currentPage, on, schedule } from "./state.js";
import { ACTIVE, eventMark, fresh, liveOf, noteLive, page, seconds, shownId, visible } from "./comm-state.js";
import { imageSettled, renderImage, renderJobButtons, renderJobs, renderPrompt, resultParts, stateCell } from "./comm-job.js";
import { gatherOptions, renderGate, renderPlan, renderProcedures } from "./comm-procedures.js";

const JOBS_LISTED = 20;

// -- data -----------------------------------------------------------------------------------------

async function refreshProcedures() {
  page.procedures = await getJSON("/procedures");
  renderProcedures({ start: startJob, plan: planJob });
}

async function refreshJobs() {
  const mark = eventMark();
  const jobs = await getJSON(`/jobs?limit=${JOBS_LISTED}`);
  page.jobs = jobs.map((j) => fresh(j, mark));
  if (eventMark() === mark) {
    const running = page.jobs.find((j) => j.running);
    page.running = running ? running.id : null;
  }
  renderJobs();
  renderGate();
}

async function refreshShown() {
  const id = shownId();
  if (id === null) {
    page.job = null;
    renderJob();
    return;
  }
  const mark = eventMark();
  let view;
  try {
    view = fresh(await getJSON(`/jobs/${id}`), mark);
  } catch (err) {
    if (shownId() === id) {
      page.job = null;
      renderJob();
      $("comm-job-head").replaceChildren(el("p", { class: "problems is-warn", text: err.message }));
    }
    return;
  }
  if (shownId() !== id) return;
  page.job = view;
  if (view.running) page.running = view.id;
  renderJob();
  renderJobs();
}

async function sync() {
  const work = [refreshJobs().then(refreshShown), refreshCalibration()];
  if (!page.procedures) work.push(refreshProcedures());
  const results = await Promise.allSettled(work);
  for (const r of results) if (r.status === "rejected") console.warn("commissioning refresh failed:", r.reason);
}
// -- start and dry run ----------------------------------------------------------------------------

// The options typed in the procedure's row, or null once it has said what is wrong with them.
function optionsOf(proc, verb) {
  try {
    return gatherOptions(proc);
  } catch (err) {
    showMessage(`${verb} ${proc.name}: ${err.message}.`, true);
    return null;
  }
}

// Run `request` with page[flag] ("starting" or "planning") set: the buttons it gates wait meanwhile.
async function whileFlagged(flag, request) {
  page[flag] = true;
  renderGate();
  try {
    return await request();
  } finally {
    page[flag] = false;
    renderGate();
  }
}

async function startJob(proc) {
  const options = optionsOf(proc, "Start");
  if (options === null) return;
  const mark = eventMark();
  const created = await whileFlagged("starting", () => post("/jobs", `Start ${proc.name}`, { procedure: proc.name, options }));
  if (!created) return;
  const view = fresh(created, mark);
  showMessage(`Job ${view.id} (${proc.name}) started; it shows its plan and waits for your confirmation before the first move.`);
  // The job's first events (even its first prompts) may have come before this answer.
  if (view.running) page.running = view.id;
  page.job = view;
  if (currentPage().id !== null) location.hash = "#/commissioning"; // follow the new job
  renderJob();
  renderGate();
  schedule("comm-job", refreshShown, 0);
  schedule("comm-jobs", refreshJobs, 0);
}

async function planJob(proc) {
  const options = optionsOf(proc, "Plan");
  if (options === null) return;
  await whileFlagged("planning", async () => {
    const plan = await post("/jobs/plan", `Plan ${proc.name}`, { procedure: proc.name, options }, { open: true });
    if (plan) renderPlan(plan);
  });
}

// -- the job --------------------------------------------------------------------------------------

function renderJob() {
  const job = page.job;
  const box = $("comm-job");
  const note = $("comm-running-note");
  const other = page.running !== null && (!job || job.id !== page.running);
  note.hidden = !other;
  note.replaceChildren(...(other ? [`Job ${page.running} is running: `, el("a", { href: "#/commissioning", text: "show it" }), "."] : []));
  if (!job) {
    box.removeAttribute("data-job");
    box.removeAttribute("data-state");
    $("comm-job-head").replaceChildren(el("p", { class: "muted", text: "No commissioning job yet." }));
    $("comm-job-result").replaceChildren();
    $("comm-job-facts").replaceChildren();
    renderPrompt();
    renderImage();
    return;
  }
  box.dataset.job = String(job.id);
  box.dataset.state = job.state;
  const prog = job.progress || {};
  const total = isNum(prog.total) ? prog.total : null;
  const done = isNum(prog.done) ? prog.done : 0;
  const bar = el("progress", { id: "comm-progress", max: total || 1, value: total ? done : 0, "aria-labelledby": "comm-progress-text" });
  const progressText = total ? `${done} / ${total}` : job.state === "running" ? "not started" : "-";
  const plan = job.plan;
  const now = [`Step: ${prog.message || "-"}`, `elapsed ${seconds(prog.elapsed_s)}`];
  if (ACTIVE.has(job.state)) now.push(`time left ${seconds(prog.time_left_s)}`);
  const head = [
    el("p", { class: "job-title" }, el("strong", { text: `Job ${job.id}: ${job.procedure} ` }), stateCell("span", job.state, { class: "job-state", id: "comm-job-state" })),
    el(
      "div",
      { class: "progress" },
      bar,
      el("span", { id: "comm-progress-text", text: `Progress ${progressText}` }),
      job.state === "computing" ? el("span", { text: " computing the result" }) : null,
    ),
    prog.message || ACTIVE.has(job.state) ? el("p", { class: "job-live", id: "comm-job-live", text: now.join(", ") }) : null,
    el("button", { type: "button", class: "btn", id: "comm-cancel", text: "Cancel job", hidden: !job.running, onclick: () => cancelJob(job.id) }),
  ];
  $("comm-job-head").replaceChildren(...head.filter(Boolean));
  $("comm-job-facts").replaceChildren(
    el(
      "dl",
      { class: "kv" },
      [
        ["Plan", plan ? `${plan.poses} poses, about ${seconds(plan.estimated_robot_time_s)} of robot time${plan.dropped && plan.dropped.length ? `, ${plan.dropped.length} dropped` : ""}` : "-"],
        ["Started by", `${job.actor} via ${job.source}, ${dateTime(job.created_utc)}`],
        ["Finished", dateTime(job.finished_utc)],
        ["Options", Object.keys(job.options || {}).length ? Object.entries(job.options).map(([k, v]) => `${k} ${v}`).join(", ") : "defaults"],
      ].map(([k, v]) => [el("dt", { text: k }), el("dd", { text: v })]),
    ),
  );
  $("comm-job-result").replaceChildren(...resultParts(job));
  renderPrompt();
  renderJobButtons();
  renderImage();
}

async function cancelJob(id) {
  const btn = $("comm-cancel");
  if (btn) btn.disabled = true;
  const mark = eventMark();
  const answer = await post(`/jobs/${id}/cancel`, `Cancel job ${id}`);
  const view = answer ? fresh(answer, mark) : null;
  if (view) {
    showMessage(`Job ${id} ${view.state}${view.error ? `: ${view.error}` : ""}.`);
    if (page.job && page.job.id === id) page.job = view;
    if (page.running === id && !view.running) page.running = null;
    renderJob();
    renderGate();
    schedule("comm-jobs", refreshJobs, 0);
  } else {
    renderJobButtons();
  }
}

// -- live updates ---------------------------------------------------------------------------------

function onJob(data) {
  const id = data.job_id;
  const active = ACTIVE.has(data.state);
  const fields = { state: data.state, error: data.error, dataset: data.dataset, version_after: data.version_after };
  if (data.progress && Object.keys(data.progress).length) fields.progress = data.progress;
  if (data.plan) fields.plan = data.plan;
  if (!active) fields.prompt = null;
  noteLive(id, fields);
  if (active) page.running = id;
  else if (page.running === id) page.running = null;
  const job = page.job;
  if (job && job.id === id) {
    page.job = fresh(job, -1);
    renderJob();
    if (job.state !== data.state && visible()) schedule("comm-job", refreshShown, 50); // the result comes with the record
  } else if (shownId() === id && visible()) {
    schedule("comm-job", refreshShown, 50);
  }
  const listed = page.jobs.find((j) => j.id === id);
  if ((!listed || listed.state !== data.state) && visible()) schedule("comm-jobs", refreshJobs, 200);
  if (!active) schedule("calibration", refreshCalibration, 200);
  renderGate();
}

function onPrompt(data) {
  const id = data.job_id;
  const l = liveOf(id);
  if (data.open) {
    noteLive(id, { prompt: data.prompt });
  } else {
    const a = data.answer; // null: the prompt closed unanswered because its job ended
    page.answered = a
      ? { job_id: id, kind: data.prompt.kind, action: a.action, value: a.value, actor: a.actor || "unknown", at: new Date().toISOString() }
      : { job_id: id, kind: data.prompt.kind, action: "closed unanswered (the job ended)", value: null, actor: "nobody", at: new Date().toISOString() };
    const known = l && "prompt" in l ? l.prompt : data.prompt;
    noteLive(id, known && known.id !== data.prompt.id ? {} : { prompt: null });
  }
  if (page.job && page.job.id === id) {
    page.job = fresh(page.job, -1);
    renderPrompt();
  } else if (shownId() === id && visible()) {
    schedule("comm-job", refreshShown, 0);
  }
}

// -- wiring ---------------------------------------------------------------------------------------

// Hooks the page into the rest of the dashboard (app.js calls it once, before the page starts).
export function installCommissioning() {
  window.cellctlCommissioning = page; // a handle for a look from the browser's console
  on("event", (kind, data) => {
    switch (kind) {
      case "status": {
        const id = data.job ? data.job.id : null;
        if (id !== page.running) {
          page.running = id;
          if (visible()) {
            schedule("comm-jobs", refreshJobs, 0);
            schedule("comm-job", refreshShown, 0);
          }
        }
        renderGate();
        break;
      }
      case "state":
        renderGate();
        break;
      case "job":
        onJob(data);
        break;
      case "prompt":
        onPrompt(data);
        break;
      case "job_image":
        page.image = { ...page.image, job: data.job_id, frames: data.frames };
        if (page.job && page.job.id === data.job_id) renderImage();
        break;
      default:
        break;
    }
  });
  on("route", (p) => {
    if (p === "commissioning") schedule("comm-sync", sync, 0);
  });
  on("refresh", (p) => (p.page === "commissioning" ? sync() : null));
  on("token", () => renderGate());
  on("calibration", (cal) => {
    $("comm-versions").replaceChildren(versionsTable(cal.versions || [], cal.current ? cal.current.version : null));
    renderGate();
  });

  const img = $("comm-image");
  img.addEventListener("load", () => imageSettled(true));
  img.addEventListener("error", () => imageSettled(false));
}
