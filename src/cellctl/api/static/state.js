/* cellctl dashboard: what the page knows (the model every view reads), the page named in the
   address, the refresh scheduler and the hooks through which the commissioning page follows the
   rest. */

export const PAGES = ["overview", "cycles", "alarms", "calibration", "commissioning"];
// The six install deviations, as the trend charts and the cycle detail show them.
export const AXES = [
  { key: "dx_mm", label: "dX", unit: "mm", kind: "position" },
  { key: "dy_mm", label: "dY", unit: "mm", kind: "position" },
  { key: "dz_mm", label: "dZ", unit: "mm", kind: "position" },
  { key: "drx_deg", label: "dRx", unit: "deg", kind: "orientation" },
  { key: "dry_deg", label: "dRy", unit: "deg", kind: "orientation" },
  { key: "drz_deg", label: "dRz", unit: "deg", kind: "orientation" },
];
export const NOK_CYCLES = new Set(["failed", "interrupted"]);
export const DEFAULT_CONFIG = {
  tolerance: { position_mm: 0.5, orientation_deg: 1.0 },
  simulation: false,
  mode_change_states: [],
  status_period_s: 2,
  stale_after_s: 5,
  plc_enabled: false,
  plc_heartbeat_alarm: true,
  calibration_max_age_days: 90,
  shift_starts: ["06:00", "14:00", "22:00"],
};

export const model = {
  config: DEFAULT_CONFIG, // GET /dashboard/config over the defaults
  status: null, // GET /status, or the last status event
  alarms: { current: [], stop_reason: null }, // GET /alarms
  alarmHistory: null, // GET /alarms?history=true (read while the alarms page is shown)
  digest: [], // GET /dashboard/cycles: the recent cycles, newest first
  cycles: [], // GET /cycles with the state filter (the cycles page)
  calibration: null, // GET /calibration
  shifts: null, // GET /dashboard/shifts: good and not OK parts of the current shift and the ones before
  plc: null, // the PLC link: the newer of the status's links.plc and the last "plc" event
  currentCycle: null, // the record of the cycle running now
  liveImage: null, // {cycle_id, name} of the last "image" event
  detailId: null, // the cycle whose detail the cycles page shows
  lastMessageAt: 0, // Date.now() of the last event: when, as the page shows it
  lastMessageMono: 0, // performance.now() of it: its age, which a step of the workstation's clock does not change
  stale: true,
  source: null, // the EventSource
};

// The page and the record id the address names: #/cycles/12 is {page: "cycles", id: 12}.
export function currentPage() {
  const m = /^#\/(\w+)(?:\/(\d+))?/.exec(location.hash || "");
  const page = m && PAGES.includes(m[1]) ? m[1] : "overview";
  const id = m && m[2] ? Number(m[2]) : null;
  return { page, id };
}

// Coalesce bursts of events into one fetch per kind.
const pending = new Map();
export function schedule(name, fn, delayMs = 100) {
  if (pending.has(name)) return;
  pending.set(
    name,
    setTimeout(async () => {
      pending.delete(name);
      try {
        await fn();
      } catch (err) {
        console.warn(`refresh ${name} failed:`, err);
      }
    }, delayMs),
  );
}

// -- hooks ----------------------------------------------------------------------------------------
// "event" (kind, data): every event from /events, after the page's own handling;
// "route" (page, id): the address changed; "token" (hasToken): the token was set or forgotten;
// "calibration" (cal): GET /calibration answered; "refresh" ({page, id}): a full refresh, whose
// hooks may return a promise the refresh waits for.

const hooks = { event: [], route: [], token: [], calibration: [], refresh: [] };

export function on(name, fn) {
  hooks[name].push(fn);
}

// Calls the hooks of `name`; a failing hook is logged and the others still run. Returns the
// promises the hooks returned.
export function emit(name, ...args) {
  const out = [];
  for (const fn of hooks[name]) {
    try {
      out.push(fn(...args));
    } catch (err) {
      console.error(`${name} hook failed:`, err);
    }
  }
  return out.filter((r) => r instanceof Promise);
}
