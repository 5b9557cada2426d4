/* cellctl dashboard: the trend chart, an SVG drawn at the size it is shown (text sizes are screen
   pixels). The scale follows the data and is written on the chart:
   - with a tolerance band (the install deviations) the axis is symmetric about zero and reaches
     max(|data|) * 1.2, so errors of 0.05 mm against a 0.5 mm band do not look flat; when the band
     is wider than that, its edges are drawn as arrows at the top and bottom with their value
     ("band +-0.50 off scale"), and points outside the band are marked;
   - without one (the cycle time) the scale is robust: up to 1.8 x the median (or 1.25 x the upper
     quartile, if more), so one slow cycle (a self-calibration) does not flatten the rest; a point
     above it is clipped to the top edge, drawn as an up arrow and labelled with its value. The
     median is drawn as a dashed line.
   A point with `counted: false` (a failed cycle's partial time) is drawn hollow, off the line, and
   left out of the headline value, the median and the scale. */

import { el, svg } from "./dom.js";
import { isNum, num, signed } from "./format.js";

const BAND_HEADROOM = 1.2;
const ROBUST_MEDIANS = 1.8;
const ROBUST_QUARTILE = 1.25;

function quantile(sorted, q) {
  const pos = (sorted.length - 1) * q;
  const i = Math.floor(pos);
  return i + 1 < sorted.length ? sorted[i] + (sorted[i + 1] - sorted[i]) * (pos - i) : sorted[i];
}

// [lo, hi] of the axis, and the median for a chart without a band.
function scaleOf(ys, band) {
  const peak = Math.max(...ys.map(Math.abs));
  if (isNum(band)) {
    const hi = peak > 0 ? peak * BAND_HEADROOM : band * BAND_HEADROOM;
    return { lo: -hi, hi, median: null };
  }
  const sorted = ys.slice().sort((a, b) => a - b);
  const median = quantile(sorted, 0.5);
  const robust = Math.max(median * ROBUST_MEDIANS, quantile(sorted, 0.75) * ROBUST_QUARTILE);
  const hi = Math.max(Math.min(sorted[sorted.length - 1] * 1.05, robust), 1e-9);
  const lo = Math.max(0, Math.min(sorted[0], median) - (hi - median) * 0.5);
  return { lo, hi, median };
}

export function chart({ title, unit, band, points, digits, emptyText, width, height, uncountedNote }) {
  const W = Math.max(200, Math.round(width || 300)), H = height || 150, L = 58, R = 12, T = 34, B = 22;
  const values = points.filter((p) => isNum(p.y));
  const counted = values.filter((p) => p.counted !== false);
  const uncounted = values.length - counted.length;
  const box = el("div", { class: "chart" });
  const root = svg("svg", { viewBox: `0 0 ${W} ${H}`, width: W, height: H, role: "img" });
  const latest = counted.length ? counted[counted.length - 1].y : null;
  const hasBand = isNum(band);
  const outside = (v) => hasBand && Math.abs(v) > band;
  root.append(svg("text", { x: 6, y: 19, class: "chart-title", text: `${title} [${unit}]` }));
  if (isNum(latest)) {
    root.append(
      svg("text", { x: W - R, y: 19, "text-anchor": "end", class: "chart-value" + (outside(latest) ? " out" : ""), text: hasBand ? signed(latest, digits) : num(latest, digits) }),
    );
  }
  if (!values.length) {
    root.append(svg("text", { x: W / 2, y: H / 2 + 8, "text-anchor": "middle", class: "empty", text: emptyText || "no cycles yet" }));
    root.setAttribute("aria-label", `${title}: ${emptyText || "no cycles yet"}`);
    box.append(root);
    return box;
  }
  const { lo, hi, median } = scaleOf((counted.length ? counted : values).map((p) => p.y), band);
  const hasMedian = counted.length > 0;
  const n = points.length;
  const xAt = (i) => L + (n === 1 ? (W - L - R) / 2 : (i * (W - L - R)) / (n - 1));
  const yAt = (v) => T + ((hi - Math.min(Math.max(v, lo), hi)) * (H - T - B)) / (hi - lo);
  const tick = (v, text) => svg("text", { class: "tick", x: L - 4, y: yAt(v) + 5, "text-anchor": "end", text });
  const scaleDigits = hi < 0.1 ? 3 : hi < 10 ? 2 : 1;
  let bandState = "none";
  if (hasBand) {
    bandState = band <= hi ? "shown" : "off-scale";
    if (bandState === "shown") {
      root.append(svg("rect", { class: "band", x: L, y: yAt(band), width: W - L - R, height: yAt(-band) - yAt(band) }));
      for (const v of [band, -band]) root.append(svg("line", { class: "tol", x1: L, x2: W - R, y1: yAt(v), y2: yAt(v) }));
    } else {
      // The band reaches beyond the scale: its edges as arrows at the chart's edges, with the value.
      const x = W - R - 8;
      root.append(svg("rect", { class: "band", x: L, y: T, width: W - L - R, height: H - T - B }));
      root.append(svg("polygon", { class: "band-edge", points: `${x - 6},${T + 8} ${x},${T} ${x + 6},${T + 8}` }));
      root.append(svg("polygon", { class: "band-edge", points: `${x - 6},${H - B - 8} ${x},${H - B} ${x + 6},${H - B - 8}` }));
      root.append(svg("text", { class: "tick band-note", x: L + 4, y: T + 14, text: `band \u00b1${num(band, 2)} off scale` }));  // inside the plot, clear of the cycle labels
    }
    root.append(svg("line", { class: "axis", x1: L, x2: W - R, y1: yAt(0), y2: yAt(0) }));
    root.append(tick(0, "0"), tick(hi, signed(hi, scaleDigits)), tick(lo, signed(lo, scaleDigits)));
  } else {
    root.append(svg("line", { class: "axis", x1: L, x2: W - R, y1: yAt(lo), y2: yAt(lo) }));
    root.append(tick(lo, num(lo, 1)), tick(hi, num(hi, 1)));
    if (hasMedian) {
      root.append(svg("line", { class: "tol", x1: L, x2: W - R, y1: yAt(median), y2: yAt(median) }));
      root.append(svg("text", { class: "tick", x: L + 4, y: yAt(median) - 4, text: `median ${num(median, digits)}` }));
    }
  }
  const path = [];
  points.forEach((p, i) => {
    if (isNum(p.y) && p.counted !== false) path.push(`${xAt(i).toFixed(1)},${yAt(p.y).toFixed(1)}`);
  });
  root.append(svg("polyline", { class: "series", points: path.join(" ") }));
  let outCount = 0;
  let clipped = 0;
  points.forEach((p, i) => {
    if (!isNum(p.y)) return;
    const out = outside(p.y);
    if (out) outCount += 1;
    const tip = svg("title", { text: `cycle ${p.id}: ${hasBand ? signed(p.y, digits) : num(p.y, digits)} ${unit}` });
    if (p.y > hi || p.y < lo) {
      // Clipped to the edge: an arrow pointing the way the value went, and the value itself.
      if (p.counted !== false) clipped += 1;
      const x = xAt(i), up = p.y > hi, y = up ? T : H - B, d = up ? 9 : -9;
      root.append(svg("polygon", { class: "pt clipped", points: `${x - 6},${y + d} ${x},${y} ${x + 6},${y + d}` }, tip));
      root.append(svg("text", { class: "tick clip-note", x: Math.min(x + 8, W - R - 40), y: up ? T + 12 : H - B - 4, text: num(p.y, digits) }));
      return;
    }
    const cls = "pt" + (out ? " out" : "") + (p.nok || p.counted === false ? " nok" : "");
    root.append(svg("circle", { class: cls, cx: xAt(i), cy: yAt(p.y), r: out ? 5 : 3.5 }, tip));
  });
  if (n === 1) {
    root.append(svg("text", { class: "tick", x: xAt(0), y: H - 4, "text-anchor": "middle", text: `cycle ${points[0].id}` }));
  } else {
    root.append(svg("text", { class: "tick", x: L, y: H - 4, text: `cycle ${points[0].id}` }));
    root.append(svg("text", { class: "tick", x: W - R, y: H - 4, "text-anchor": "end", text: `cycle ${points[n - 1].id}` }));
  }
  const scale = hasBand ? `\u00b1${num(hi, scaleDigits)} ${unit}` : `${num(lo, 1)} to ${num(hi, 1)} ${unit}`;
  const head = counted.length ? `latest ${num(latest, digits)} ${unit}` : "none counted yet";
  const label = [`${title}: ${counted.length} cycles, ${head}, scale ${scale}`];
  if (hasBand) label.push(`${outCount} outside plus or minus ${band} ${unit}`, bandState === "off-scale" ? "tolerance band beyond the scale" : "tolerance band shown");
  else label.push(hasMedian ? `median ${num(median, digits)} ${unit}` : "no median", `${clipped} outside the scale, clipped`);
  if (uncounted) label.push(`${uncounted} ${uncountedNote || "more drawn hollow, not counted"}`);
  root.setAttribute("aria-label", label.join(", "));
  box.dataset.outside = String(outCount);
  box.dataset.points = String(values.length);
  box.dataset.counted = String(counted.length);
  box.dataset.scale = scale;
  box.dataset.band = bandState;
  box.dataset.clipped = String(clipped);
  box.append(root);
  return box;
}

// The width of one chart in `container` laid out in as many columns (up to `columns`) as fit
// charts at least `minWidth` px wide; sets the container's columns to match.
export function chartWidth(container, columns, minWidth = 260) {
  const gap = 6;
  const w = container.clientWidth || 900;
  const fit = Math.max(1, Math.min(columns, Math.floor((w + gap) / (minWidth + gap))));
  container.style.gridTemplateColumns = `repeat(${fit}, minmax(0, 1fr))`;
  return Math.floor((w - gap * (fit - 1)) / fit) - 2;
}
