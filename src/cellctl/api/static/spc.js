/* cellctl dashboard: the closed loops over measured install results (/status's spc part), one per
   recipe: per axis the estimate of the cell's systematic deviation and the offset the next install
   takes out, the samples counted, and a drift that asks for recalibration. */

import { $, el, setClass } from "./dom.js";
import { isNum, signed } from "./format.js";
import { AXES, model } from "./state.js";

export function renderSpc() {
  const node = $("spc");
  const spc = model.status ? model.status.spc : null;
  if (!node) return;
  if (!spc) {
    node.replaceChildren(el("p", { class: "muted", text: "No closed loop in this service." }));
    return;
  }
  const loops = spc.recipes && spc.recipes.length ? spc.recipes : [spc];
  node.replaceChildren(...loops.flatMap((loop) => renderLoop(loop, loops.length > 1)));
}

/* One recipe's loop (each recipe's install pose is taught on its own, so each has its own loop). */
function renderLoop(spc, named) {
  const drifting = new Set((spc.drifting || []).map((d) => d.axis));
  const head = el("tr", {}, el("th", { scope: "col", text: "" }), AXES.map((ax) => el("th", { scope: "col", text: `${ax.label} ${ax.unit}` })));
  const row = (label, values) =>
    el(
      "tr",
      {},
      el("th", { scope: "row", text: label }),
      AXES.map((ax) => {
        const v = values ? values[ax.key] : null;
        const td = el("td", { class: "num", text: isNum(v) ? signed(v, 3) : "-" });
        setClass(td, "is-alarm", drifting.has(ax.key));
        return td;
      }),
    );
  const state = spc.enabled ? "on" : "off (watching only)";
  const who = named ? `${spc.recipe}: loop` : "Loop";
  const note = `${who} ${state}; ${spc.samples} result${spc.samples === 1 ? "" : "s"} counted (running mean, EWMA from ${spc.min_samples}).`;
  const parts = [
    el("p", { class: "muted", text: note }),
    el(
      "table",
      { class: "data", "data-spc": "table", "data-recipe": spc.recipe || "" },
      el("thead", {}, head),
      el("tbody", {}, [row("Estimate", spc.estimate), row("Next offset", spc.offset)]),
    ),
  ];
  if (drifting.size) {
    const what = spc.drifting.map((d) => `${d.axis} ${d.kind} ${signed(d.value, 3)} (limit ${d.limit})`).join(", ");
    const whose = named ? `${spc.recipe} drifts` : "Drift";
    parts.push(el("p", { class: "is-alarm", "data-spc": "drift", text: `${whose}: ${what}. Run cellctl calibrate verify, then recalibrate.` }));
  }
  return parts;
}
