/* cellctl dashboard: how numbers, times and nested records read on the page. No DOM here. */

export function isNum(v) {
  return typeof v === "number" && Number.isFinite(v);
}

export function num(v, digits = 3) {
  return isNum(v) ? v.toFixed(digits) : "-";
}

export function signed(v, digits = 3) {
  return isNum(v) ? (v >= 0 ? "+" : "") + v.toFixed(digits) : "-";
}

export function figure(v) {
  if (Number.isInteger(v)) return String(v);
  if (!isNum(v)) return String(v);
  const a = Math.abs(v);
  if (a !== 0 && (a < 1e-3 || a >= 1e6)) return v.toExponential(3);
  return String(Number(v.toPrecision(6)));
}

export function clock(iso) {
  if (!iso) return "-";
  const d = new Date(iso);
  return Number.isNaN(d.getTime()) ? iso : d.toLocaleTimeString([], { hour12: false });
}

const pad = (n) => String(n).padStart(2, "0");

// The local date of an ISO time or a Date: 2026-03-05.
export function day(t) {
  const d = t instanceof Date ? t : new Date(t);
  return Number.isNaN(d.getTime()) ? String(t) : `${d.getFullYear()}-${pad(d.getMonth() + 1)}-${pad(d.getDate())}`;
}

export function dateTime(iso) {
  if (!iso) return "-";
  const d = new Date(iso);
  if (Number.isNaN(d.getTime())) return iso;
  return `${day(d)} ${d.toLocaleTimeString([], { hour12: false })}`;
}

// A nested record as [dotted key, text] rows, for the key-value lists (see kvList in dom.js).
export function flatten(value, prefix = "", out = []) {
  if (value === null || value === undefined) {
    out.push([prefix, "-"]);
  } else if (Array.isArray(value)) {
    const scalar = (v) => v === null || ["number", "string", "boolean"].includes(typeof v);
    if (value.length === 0) {
      out.push([prefix, "none"]);
    } else if (value.every((v) => typeof v === "number")) {
      out.push([prefix, "[" + value.map(figure).join(", ") + "]"]);
    } else if (value.every((v) => Array.isArray(v) && v.every((x) => typeof x === "number"))) {
      out.push([prefix, "[" + value.map((r) => "[" + r.map(figure).join(", ") + "]").join(", ") + "]"]);
    } else if (value.every((v) => v && typeof v === "object" && !Array.isArray(v) && Object.values(v).every(scalar))) {
      // A list of small records (e.g. the laser spots): one line each.
      value.forEach((v, i) => {
        const line = Object.entries(v).map(([k, x]) => `${k} ${typeof x === "number" ? figure(x) : String(x)}`);
        out.push([`${prefix}[${i}]`, line.join(", ")]);
      });
    } else {
      value.forEach((v, i) => flatten(v, `${prefix}[${i}]`, out));
    }
  } else if (typeof value === "object") {
    const keys = Object.keys(value);
    if (keys.length === 0) out.push([prefix, "-"]);
    for (const k of keys) flatten(value[k], prefix ? `${prefix}.${k}` : k, out);
  } else if (typeof value === "number") {
    out.push([prefix, figure(value)]);
  } else {
    out.push([prefix, String(value)]);
  }
  return out;
}
