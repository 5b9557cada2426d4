/* cellctl dashboard: the cycles page (#/cycles, #/cycles/12): the cycle history with its filters
   (state from the API, part id in the page) and the selected cycle's detail: its figures, true
   install error (simulation), images and steps. */

import { getJSON, getLatest, thumbUrl } from "./api.js";
import { tokenImage } from "./images.js";
import { figureList } from "./figures.js";
import { $, el, setClass } from "./dom.js";
import { dateTime, isNum, num, signed } from "./format.js";
import { AXES, NOK_CYCLES, model, schedule } from "./state.js";

export async function refreshCycleTable() {
  const state = $("filter-state").value;
  const url = "/cycles?limit=200" + (state ? `&state=${encodeURIComponent(state)}` : "");
  const cycles = await getLatest("cycles", url); // an answer from before the filter changed is dropped
  if (cycles === null) return;
  model.cycles = cycles;
  renderCycleTable();
}

export async function refreshDetail() {
  if (model.detailId === null) return;
  const id = model.detailId;
  try {
    const record = await getJSON(`/cycles/${id}`);
    if (model.detailId === id) renderDetail(record);
  } catch (err) {
    if (model.detailId === id) $("cycle-detail").replaceChildren(el("p", { class: "is-warn problems", text: err.message }));
  }
}

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

// The cell-clock seconds of each step (robot time; simulated seconds on the simulated cell), largest first.
function stepTimes(times) {
  if (!times || typeof times !== "object") return "-";
  const rows = Object.entries(times).filter(([, v]) => isNum(v) && v >= 0.05).sort((a, b) => b[1] - a[1]);
  return rows.length ? rows.map(([k, v]) => `${k} ${v.toFixed(1)} s`).join(", ") : "-";
}

// The alarm code a failed cycle's result names (0 when it ended well), or "-".
function errorCode(res) {
  return isNum(res.error_code) && res.error_code !== 0 ? String(res.error_code) : "-";
}

function renderDetail(rec) {
  const res = rec.result || {};
  const parts = [
    el("h2", { text: `Cycle ${rec.id}: ${rec.state}` }),
    rec.error ? el("p", { class: "problems is-alarm", text: rec.error }) : null,
    el(
      "dl",
      { class: "kv kv-inline facts" },
      [
        ["Part", rec.part_id],
        ["Car", rec.car_id || "-"],
        ["Recipe", rec.recipe],
        ["Requested by", `${rec.actor} via ${rec.source}`],
        ["Created", dateTime(rec.created_at)],
        ["Started", dateTime(rec.started_at)],
        ["Finished", dateTime(rec.finished_at)],
        ["Cycle time", isNum(res.cycle_time_s) ? `${res.cycle_time_s.toFixed(2)} s` : "-"],
        ["Time per step", stepTimes(res.step_time_s)],
        ["Correction", `${triple(res.correction_mm, 3)} mm, ${triple(res.correction_deg, 4)} deg`],
        ["Interrupted in", rec.interrupted_step || "-"],
        ["Error code", errorCode(res)], // the alarm code that says why it failed (e.g. the first-out 1101)
      ].map(([k, v]) => el("div", { class: "pair" }, el("dt", { text: k }), el("dd", { text: v }))),
    ),
  ];
  const deviations = [
    ["Measured after the install", rec.measured_deviation],
    ["True (simulation)", rec.true_error],
  ].filter(([, d]) => d);
  if (deviations.length) {
    const verdict = rec.part_ok === false ? " (part not OK)" : rec.part_ok === true ? " (part OK)" : "";
    parts.push(el("h3", { text: `Install deviation${verdict}` }));
    const tol = model.config.tolerance;
    const row = ([label, d]) => {
      const cells = AXES.map((ax) => {
        const v = d[ax.key];
        const band = ax.kind === "position" ? tol.position_mm : tol.orientation_deg;
        const td = el("td", { class: "num", text: signed(v, 4) });
        setClass(td, "is-alarm", isNum(v) && Math.abs(v) > band);
        return td;
      });
      return el("tr", {}, el("th", { scope: "row", text: label }), ...cells);
    };
    parts.push(
      el(
        "table",
        { class: "data" },
        el("thead", {}, el("tr", {}, el("th", { scope: "col", text: "" }), AXES.map((ax) => el("th", { scope: "col", text: `${ax.label} ${ax.unit}` })))),
        el("tbody", {}, deviations.map(row)),
      ),
    );
  }
  parts.push(el("h3", { text: "Images" }));
  const images = (rec.images || []).map((i) =>
    el(
      "a",
      { href: i.url, target: "_blank", rel: "noopener", "data-token-open": true },
      tokenImage(thumbUrl(rec.id, i.name, 320), { alt: `Annotated image ${i.name} of cycle ${rec.id} (${i.step})` }),
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
      el("td", { class: "num", text: num(isNum((s.figures || {}).time_s) ? s.figures.time_s : s.duration_s, 3) }),
      okCell,
      el("td", {}, Object.keys(s.figures || {}).length ? figureList(s.figures) : "-", s.error ? el("p", { text: s.error }) : null),
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

export function bindCycles() {
  $("filter-state").addEventListener("change", () => schedule("cycles", refreshCycleTable, 0));
  $("filter-part").addEventListener("input", renderCycleTable);
  $("cycle-filters").addEventListener("submit", (e) => e.preventDefault());
}
