/* cellctl dashboard: when the calibration set falls due. Each part's expiry is the service's own
   (GET /calibration: current.parts[name].expires_utc, from the validity the service applies to
   that part); the dashboard never re-derives it from the configuration. The set is due when its
   first part expires; `now` is the service's clock (clock.js). No DOM here. */

const DAY_MS = 86400e3;
const HOUR_MS = 3600e3;
export const DUE_SOON_DAYS = 7; // the tile asks for attention this long before

// The expiry of one part (a Date), or null (failed, or the service gave none).
export function partDue(p) {
  const t = p && p.expires_utc ? Date.parse(p.expires_utc) : NaN;
  return Number.isNaN(t) ? null : new Date(t);
}

// {due: Date, part, msLeft, daysLeft (fractional days, negative when overdue)} of the part that
// expires first, or null (no part with an expiry, e.g. the twin's truth).
export function calibrationDue(cal, now) {
  const parts = (cal && cal.current && cal.current.parts) || {};
  let first = null;
  for (const [name, p] of Object.entries(parts)) {
    const due = p && p.status === "ok" ? partDue(p) : null;
    if (due && (!first || due < first.due)) first = { due, part: name };
  }
  if (first) {
    first.msLeft = first.due.getTime() - now;
    first.daysLeft = first.msLeft / DAY_MS;
  }
  return first;
}

// How far off `due` is, in words: "overdue" (by less than a day), "overdue by 3 d", "in 40 min",
// "in 5 h", "in 12 d" (whole units, rounded down; minutes up).
export function dueIn(due) {
  const ms = due.msLeft;
  if (ms <= 0) return -ms < DAY_MS ? "overdue" : `overdue by ${Math.floor(-ms / DAY_MS)} d`;
  if (ms < HOUR_MS) return `in ${Math.ceil(ms / 60e3)} min`;
  return ms < DAY_MS ? `in ${Math.floor(ms / HOUR_MS)} h` : `in ${Math.floor(ms / DAY_MS)} d`;
}

// The milliseconds until the next part expires after `now` (null: none ahead), so a page can
// read the set again when a shown due time passes.
export function nextExpiryMs(cal, now) {
  const parts = (cal && cal.current && cal.current.parts) || {};
  let next = null;
  for (const p of Object.values(parts)) {
    const due = p && p.status === "ok" ? partDue(p) : null;
    const ms = due ? due.getTime() - now : NaN;
    if (ms > 0 && (next === null || ms < next)) next = ms;
  }
  return next;
}
