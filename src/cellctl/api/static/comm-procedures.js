/* cellctl dashboard, commissioning page: the procedures panel. One row per procedure with what it
   needs calibrated, its options and its Start and Dry run buttons; the gate that says why a job
   cannot start now; the plan of a dry run. What the buttons do comes from commissioning.js. */

import { token } from "./api.js";
import { $, el } from "./dom.js";
import { figure } from "./format.js";
import { model } from "./state.js";
import { JOB_STATES, NUMBER_OPTIONS, page, seconds } from "./comm-state.js";
import { renderJobButtons } from "./comm-job.js";

const CYCLE_STATES = new Set(["EXECUTE", "HELD", "HOLDING", "SUSPENDED", "SUSPENDING", "UNHOLDING", "UNSUSPENDING"]); // a cycle may be in progress

function partStatus(name) {
  const cur = model.calibration && model.calibration.current;
  const p = cur && cur.parts ? cur.parts[name] : null;
  return p ? p.status : null;
}

function optionInputs(proc) {
  const out = [];
  for (const opt of proc.options) {
    const id = `comm-opt-${proc.name}-${opt}`;
    if (NUMBER_OPTIONS[opt]) {
      out.push(
        el("label", { for: id, text: NUMBER_OPTIONS[opt] }),
        el("input", { id, type: "number", min: 1, step: 1, size: 5, inputmode: "numeric", placeholder: "default", "data-option": opt }),
      );
    } else if (opt === "store") {
      out.push(
        el("label", { class: "check" }, el("input", { id, type: "checkbox", checked: true, "data-option": opt }), "store the result"),
      );
    } else if (opt === "recipe" && (proc.choices.recipe || []).length > 1) {
      // the recipe taught: each has its own teaching and nine-point map
      out.push(
        el("label", { for: id, text: "recipe" }),
        el("select", { id, "data-option": opt }, proc.choices.recipe.map((r) => el("option", { value: r, text: r }))),
      );
    }
  }
  return out;
}

// `start(proc)`, `plan(proc)`: what the row's Start and Dry run buttons do.
export function renderProcedures({ start, plan }) {
  const procs = page.procedures || [];
  if (!procs.length) {
    $("comm-procedures").replaceChildren(el("p", { class: "muted", text: "The service offers no procedures." }));
    return;
  }
  const rows = procs.map((p) =>
    el(
      "tr",
      { "data-procedure": p.name },
      el("th", { scope: "row" }, p.name, el("br"), el("span", { class: "muted small", text: p.command })),
      el("td", { class: "needs", text: "-" }),
      el("td", {}, el("div", { class: "options" }, optionInputs(p))),
      el(
        "td",
        { class: "actions" },
        el("button", { type: "button", class: "btn btn-small", "data-start": p.name, text: "Start", onclick: () => start(p) }),
        el("button", { type: "button", class: "btn btn-small", "data-plan": p.name, text: "Dry run (plan)", onclick: () => plan(p) }),
      ),
    ),
  );
  $("comm-procedures").replaceChildren(
    el(
      "table",
      { class: "data", id: "comm-proc-table" },
      el("thead", {}, el("tr", {}, ["Procedure", "Needs", "Options", "Run"].map((h) => el("th", { scope: "col", text: h })))),
      el("tbody", {}, rows),
    ),
  );
  renderGate();
}

// Why a procedure cannot start now, or null.
function startBlocked(proc) {
  if (!token()) return "enter the operator token first";
  if (page.starting) return "a start is on its way";
  const st = model.status;
  if (page.running !== null) return `job ${page.running} is running: one job at a time; wait for it or cancel it`;
  if (st && !JOB_STATES.has(st.state)) {
    return `jobs start in STOPPED or IDLE only; the cell is ${st.state} (${st.state === "ABORTED" ? "send Clear first" : CYCLE_STATES.has(st.state) ? "send Stop once the cycle in progress has ended: Stop ends it at once" : "send Stop first"})`;
  }
  const missing = proc.needs.filter((n) => partStatus(n) !== "ok");
  if (missing.length) return `${proc.name} needs ${missing.join(", ")} calibrated first`;
  return null;
}

export function renderGate() {
  const st = model.status;
  const notes = [];
  if (!token()) notes.push("Enter the operator token (above) to start jobs, answer prompts and cancel.");
  if (st && !JOB_STATES.has(st.state)) notes.push(`Jobs start in STOPPED or IDLE only; the cell is ${st.state}.`);
  if (page.running !== null) notes.push(`Job ${page.running} is running; one job runs at a time.`);
  $("comm-gate").textContent = notes.join(" ");
  for (const p of page.procedures || []) {
    const row = document.querySelector(`#comm-proc-table tr[data-procedure="${p.name}"]`);
    if (!row) continue;
    const needs = row.querySelector(".needs");
    needs.replaceChildren(
      ...(p.needs.length
        ? [p.needs.map((n) => `${n} ${partStatus(n) || "missing"}`).join(", ")]
        : ["nothing"]),
    );
    const start = row.querySelector("[data-start]");
    const why = startBlocked(p);
    start.disabled = why !== null;
    start.title = why ? `Cannot start: ${why}` : `Start ${p.name}: the robot moves after you confirm the plan`;
    row.querySelector("[data-plan]").disabled = page.planning;
  }
  renderJobButtons();
}

export function gatherOptions(proc) {
  const options = {};
  for (const input of document.querySelectorAll(`#comm-proc-table tr[data-procedure="${proc.name}"] [data-option]`)) {
    const opt = input.dataset.option;
    if (input.type === "checkbox") {
      if (!input.checked) options[opt] = false;
    } else if (input.tagName === "SELECT") {
      options[opt] = input.value;
    } else if (input.value.trim() !== "") {
      const v = Number(input.value);
      if (!Number.isInteger(v) || v <= 0) throw new Error(`${NUMBER_OPTIONS[opt] || opt}: give a whole number, or leave it empty for the default`);
      options[opt] = v;
    }
  }
  return options;
}

export function renderPlan(plan) {
  const rot = plan.rotation || {};
  const rows = [
    ["Poses", String(plan.poses)],
    ["Robot time", `about ${seconds(plan.estimated_robot_time_s)} at up to ${figure(plan.speed_mm_s)} mm/s, ${figure(plan.speed_deg_s)} deg/s`],
    ["Rotation", Object.entries(rot).map(([k, v]) => `${k} ${figure(v)}`).join(", ") || "-"],
    ["Dropped", plan.dropped.length ? `${plan.dropped.length}: ${plan.dropped.slice(0, 3).join("; ")}${plan.dropped.length > 3 ? "; ..." : ""}` : "none"],
  ];
  if (plan.first_pose) {
    const fp = plan.first_pose;
    const at = Array.isArray(fp.position_mm) ? fp.position_mm.map((v) => v.toFixed(0)).join(", ") : "-";
    rows.push(["First pose", `${fp.label || ""} (${at}) mm`]);
  }
  $("comm-plan").replaceChildren(
    el(
      "div",
      { class: "plan", "data-procedure": plan.procedure },
      el("h3", { text: `Plan for ${plan.procedure} (dry run: nothing moved)` }),
      el("dl", { class: "kv" }, rows.map(([k, v]) => [el("dt", { text: k }), el("dd", { text: v })])),
    ),
  );
}
