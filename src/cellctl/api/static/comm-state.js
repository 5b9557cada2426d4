/* cellctl dashboard, commissioning page: what the page knows (the procedures, the recent jobs, the
   job shown, the one running) and what the event stream said about each job since its record was
   read. */

import { isNum } from "./format.js";
import { currentPage } from "./state.js";

export const JOB_STATES = new Set(["STOPPED", "IDLE"]); // the PackML states a job may start in
export const ACTIVE = new Set(["running", "computing"]);
export const ALARM_JOBS = new Set(["failed"]);
export const WARN_JOBS = new Set(["refused", "interrupted"]);
export const NUMBER_OPTIONS = { views: "board views", poses: "laser poses" };

export const page = {
  procedures: null, // ProcedureView[] from GET /procedures
  jobs: [], // recent JobViews, newest first
  job: null, // the JobView shown
  running: null, // id of the job the service runs now
  answered: null, // the last answer seen on the event stream: {job_id, kind, action, value, actor}
  promptShown: null, // id of the prompt whose form is on the page (kept while the engineer types)
  image: { job: null, frames: 0, loading: false, again: false },
  planning: false,
  starting: false,
};

export const visible = () => currentPage().page === "commissioning";

// The job the page shows: the one named in the address (#/commissioning/7), else the running
// one, else the newest.
export function shownId() {
  const { page: p, id } = currentPage();
  if (p === "commissioning" && id !== null) return id;
  if (page.running !== null) return page.running;
  return page.jobs.length ? page.jobs[0].id : null;
}

export function seconds(s) {
  if (!isNum(s)) return "-";
  if (s < 90) return `${s.toFixed(0)} s`;
  const m = Math.floor(s / 60);
  return `${m} min ${String(Math.round(s - 60 * m)).padStart(2, "0")} s`;
}

// -- what the event stream said -------------------------------------------------------------------

// What the event stream said last about each job. A record fetched while events came in may be
// older than they are: what they carry wins over it (see fresh()).
const LIVE_FIELDS = ["state", "progress", "plan", "error", "dataset", "version_after", "prompt"];
const live = new Map();
let seq = 0; // job and prompt events seen

// The count of job and prompt events seen so far: take it before a request, give it to fresh().
export function eventMark() {
  return seq;
}

// What the events said about job `id` ({...fields, seq}), or undefined.
export function liveOf(id) {
  return live.get(id);
}

export function noteLive(id, fields) {
  const cur = live.get(id) || {};
  live.delete(id); // re-inserted last: the map keeps the newest few jobs
  live.set(id, Object.assign(cur, fields, { seq: ++seq }));
  while (live.size > 8) live.delete(live.keys().next().value);
}

// The record `view`, with what events that came after `mark` said about it.
export function fresh(view, mark) {
  const l = live.get(view.id);
  if (!l || l.seq <= mark) return view;
  const out = { ...view };
  for (const k of LIVE_FIELDS) if (k in l) out[k] = l[k];
  out.running = ACTIVE.has(out.state);
  return out;
}
