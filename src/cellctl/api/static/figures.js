/* cellctl dashboard: a nested record (a step's figures, a calibration part's quality) as a short
   key-value list. Plain figures show as they are; a group that would take more than a couple of
   lines (a list of laser spots, a calibration summary, a matrix) is folded into a closed
   <details> with its size, so one step stays a few lines tall however much it recorded. */

import { el } from "./dom.js";
import { flatten } from "./format.js";

const LONG_TEXT = 60; // characters: a longer value is folded too

// `inline`: the pairs flow side by side and wrap (a step's plain figures); else one a line.
function kv(rows, inline = false) {
  const pairs = rows.map(([k, v]) => el("div", { class: "pair" }, el("dt", { text: k || "value" }), el("dd", { text: v })));
  return el("dl", { class: inline ? "kv kv-inline" : "kv" }, pairs);
}

export function figureList(obj) {
  if (obj === null || typeof obj !== "object" || Array.isArray(obj)) return kv(flatten(obj));
  const plain = [];
  const folded = [];
  for (const [key, value] of Object.entries(obj)) {
    const rows = flatten(value, key);
    if (rows.length === 1 && rows[0][1].length <= LONG_TEXT) {
      plain.push(rows[0]);
    } else {
      const short = rows.map(([k, v]) => [k.startsWith(key) ? k.slice(key.length).replace(/^\./, "") || key : k, v]);
      const size = rows.length === 1 ? `${rows[0][1].length} characters` : `${rows.length} figures`;
      folded.push(el("details", { class: "fold", "data-figure": key }, el("summary", {}, el("strong", { text: key }), ` (${size})`), kv(short)));
    }
  }
  return el("div", { class: "figures" }, plain.length ? kv(plain, true) : null, folded);
}
