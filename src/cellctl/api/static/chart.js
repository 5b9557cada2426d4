/* cellctl dashboard: the trend chart, an SVG drawn at the size it is shown. With a tolerance band
   (the install deviations) the axis is symmetric about zero and points outside the band are marked;
   without one (the cycle time) it starts at zero. */

import { el, svg } from "./dom.js";
import { isNum, num, signed } from "./format.js";

export function chart({ title, unit, band, points, digits, emptyText, width, height }) {
  // Drawn at the size it is shown, so text sizes are screen pixels.
  const W = Math.max(200, Math.round(width || 300)), H = height || 150, L = 52, R = 10, T = 28, B = 20;
  const values = points.filter((p) => isNum(p.y));
  const box = el("div", { class: "chart" });
  const label = [];
  const root = svg("svg", { viewBox: `0 0 ${W} ${H}`, role: "img" });
  const latest = values.length ? values[values.length - 1].y : null;
  const outside = (v) => isNum(band) && Math.abs(v) > band;
  root.append(svg("text", { x: 6, y: 19, class: "chart-title", text: `${title} [${unit}]` }));
  if (isNum(latest)) {
    root.append(
      svg("text", { x: W - R, y: 19, "text-anchor": "end", class: "chart-value" + (outside(latest) ? " out" : ""), text: isNum(band) ? signed(latest, digits) : num(latest, digits) }),
    );
  }
  if (!values.length) {
    root.append(svg("text", { x: W / 2, y: H / 2 + 8, "text-anchor": "middle", class: "empty", text: emptyText || "no cycles yet" }));
    root.setAttribute("aria-label", `${title}: ${emptyText || "no cycles yet"}`);
    box.append(root);
    return box;
  }
  const peak = Math.max(...values.map((p) => Math.abs(p.y)));
  let lo, hi;
  if (isNum(band)) {
    hi = Math.max(band * 1.3, peak * 1.1);
    lo = -hi;
  } else {
    lo = 0;
    hi = Math.max(peak * 1.15, 1e-9);
  }
  const n = points.length;
  const xAt = (i) => L + (n === 1 ? (W - L - R) / 2 : (i * (W - L - R)) / (n - 1));
  const yAt = (v) => T + ((hi - v) * (H - T - B)) / (hi - lo);
  if (isNum(band)) {
    root.append(svg("rect", { class: "band", x: L, y: yAt(band), width: W - L - R, height: yAt(-band) - yAt(band) }));
    for (const v of [band, -band]) {
      root.append(svg("line", { class: "tol", x1: L, x2: W - R, y1: yAt(v), y2: yAt(v) }));
      root.append(svg("text", { class: "tick", x: L - 4, y: yAt(v) + 4, "text-anchor": "end", text: signed(v, band < 1 ? 2 : 1) }));
    }
    root.append(svg("line", { class: "axis", x1: L, x2: W - R, y1: yAt(0), y2: yAt(0) }));
    root.append(svg("text", { class: "tick", x: L - 4, y: yAt(0) + 4, "text-anchor": "end", text: "0" }));
  } else {
    root.append(svg("line", { class: "axis", x1: L, x2: W - R, y1: yAt(0), y2: yAt(0) }));
    root.append(svg("text", { class: "tick", x: L - 4, y: yAt(0) + 4, "text-anchor": "end", text: "0" }));
    root.append(svg("text", { class: "tick", x: L - 4, y: yAt(peak) + 4, "text-anchor": "end", text: num(peak, 1) }));
    root.append(svg("line", { class: "tol", x1: L, x2: W - R, y1: yAt(peak), y2: yAt(peak) }));
  }
  const path = [];
  points.forEach((p, i) => {
    if (isNum(p.y)) path.push(`${xAt(i).toFixed(1)},${yAt(p.y).toFixed(1)}`);
  });
  root.append(svg("polyline", { class: "series", points: path.join(" ") }));
  let outCount = 0;
  points.forEach((p, i) => {
    if (!isNum(p.y)) return;
    const out = outside(p.y);
    if (out) outCount += 1;
    const cls = "pt" + (out ? " out" : "") + (p.nok ? " nok" : "");
    root.append(
      svg("circle", { class: cls, cx: xAt(i), cy: yAt(p.y), r: out ? 4.5 : 3 }, svg("title", { text: `cycle ${p.id}: ${signed(p.y, digits)} ${unit}` })),
    );
  });
  if (n === 1) {
    root.append(svg("text", { class: "tick", x: xAt(0), y: H - 3, "text-anchor": "middle", text: `cycle ${points[0].id}` }));
  } else {
    root.append(svg("text", { class: "tick", x: L, y: H - 3, text: `cycle ${points[0].id}` }));
    root.append(svg("text", { class: "tick", x: W - R, y: H - 3, "text-anchor": "end", text: `cycle ${points[n - 1].id}` }));
  }
  label.push(`${title}: ${values.length} cycles, latest ${signed(latest, digits)} ${unit}, largest magnitude ${num(peak, digits)} ${unit}`);
  if (isNum(band)) label.push(`${outCount} outside plus or minus ${band} ${unit}`);
  root.setAttribute("aria-label", label.join(", "));
  box.dataset.outside = String(outCount);
  box.dataset.points = String(values.length);
  box.append(root);
  return box;
}

export function chartWidth(container, columns) {
  const gap = 6;
  const w = container.clientWidth || 900;
  return Math.floor((w - gap * (columns - 1)) / columns) - 2;
}

