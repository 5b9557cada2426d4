/* cellctl dashboard: when the calibration set falls due. A part older than the configuration's
   calibration.max_age_days keeps the cell from production, so the set is due when its oldest part
   turns that old. No DOM here. */

const DAY_MS = 86400e3;
export const DUE_SOON_DAYS = 7; // the tile asks for attention this long before

// The due date of one part calibrated at `iso`, or null.
export function partDue(iso, maxAgeDays) {
  const t = iso ? Date.parse(iso) : NaN;
  return Number.isNaN(t) || !(maxAgeDays > 0) ? null : new Date(t + maxAgeDays * DAY_MS);
}

// {due: Date, part, daysLeft} of the part that falls due first, or null (no dated part, e.g. the twin's truth).
export function calibrationDue(cal, maxAgeDays, now = Date.now()) {
  const parts = (cal && cal.current && cal.current.parts) || {};
  let first = null;
  for (const [name, p] of Object.entries(parts)) {
    const due = p && p.status === "ok" ? partDue(p.calibrated_utc, maxAgeDays) : null;
    if (due && (!first || due < first.due)) first = { due, part: name };
  }
  if (first) first.daysLeft = Math.floor((first.due.getTime() - now) / DAY_MS);
  return first;
}
