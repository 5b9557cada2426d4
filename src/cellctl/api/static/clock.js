/* cellctl dashboard: the service's clock. The calibration's due times are the service's own, so "in 5 d" and
   "overdue" are reckoned on its clock (GET /calibration's now_utc), not on this browser's, which may be days off
   on a workstation. No DOM here. */

let offsetMs = 0; // the service's clock minus the browser's, as last measured

// Take the service's time `iso`, answered to a request sent at `sentMs` and received at `gotMs` (browser clock).
export function noteServiceTime(iso, sentMs, gotMs) {
  const t = Date.parse(iso);
  if (!Number.isNaN(t)) offsetMs = t - (sentMs + gotMs) / 2;
}

// Now on the service's clock (ms since the epoch).
export function serviceNow() {
  return Date.now() + offsetMs;
}
