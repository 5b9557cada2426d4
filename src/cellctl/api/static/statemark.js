/* cellctl dashboard: the PackML state's mark, a shape of its own for every state so that the
   state reads from across the cell without telling colours apart: a triangle for Execute (running),
   a hollow circle for Idle, a square for Stopped, two bars for Held, a warning triangle for
   Suspended, a crossed octagon for Aborted, a tick for Complete and an hourglass while the cell
   acts (the ..ING states). The tile's colour (style.css, by data-state) comes on top. */

import { svg } from "./dom.js";

const SHAPES = {
  run: () => [svg("polygon", { points: "7,4 21,12 7,20", class: "fill" })],
  idle: () => [svg("circle", { cx: 12, cy: 12, r: 8, class: "line" })],
  stopped: () => [svg("rect", { x: 5, y: 5, width: 14, height: 14, class: "fill" })],
  held: () => [svg("rect", { x: 5, y: 4, width: 5, height: 16, class: "fill" }), svg("rect", { x: 14, y: 4, width: 5, height: 16, class: "fill" })],
  suspended: () => [svg("polygon", { points: "12,3 22,20 2,20", class: "line" }), svg("path", { d: "M12 9v5M12 16.5v1.5", class: "line" })],
  aborted: () => [svg("polygon", { points: "8,2 16,2 22,8 22,16 16,22 8,22 2,16 2,8", class: "fill" }), svg("path", { d: "M8 8l8 8M16 8l-8 8", class: "cut" })],
  complete: () => [svg("path", { d: "M4 12l5 5 11-11", class: "line" })],
  acting: () => [svg("path", { d: "M6 3h12M6 21h12M7 3c0 6 10 6 10 9s-10 3-10 9M17 3c0 6-10 6-10 9s10 3 10 9", class: "line" })],
};

export function stateKind(state) {
  if (state === "EXECUTE") return "run";
  if (state === "IDLE") return "idle";
  if (state === "STOPPED") return "stopped";
  if (state === "HELD") return "held";
  if (state === "SUSPENDED") return "suspended";
  if (state === "ABORTED") return "aborted";
  if (state === "COMPLETE") return "complete";
  return "acting";
}

// The mark as an SVG; `kind` is stateKind(state).
export function stateMark(kind) {
  return svg("svg", { viewBox: "0 0 24 24", class: `state-mark mark-${kind}`, "aria-hidden": "true", "data-mark": kind }, SHAPES[kind]());
}
