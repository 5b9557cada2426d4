/* cellctl dashboard: the shift counters on the overview: good parts, not OK ones and the takt
   (median cycle time of the good ones) of the current shift, big, and of the two before it. The
   shifts begin at the dashboard config's shift_starts (06:00, 14:00, 22:00 unless the service
   says otherwise) in this browser's time zone, sent by its IANA name so that every shift follows its
   daylight saving time; GET /dashboard/shifts counts them. */

import { getLatest } from "./api.js";
import { $, el, setClass } from "./dom.js";
import { clock, num } from "./format.js";
import { model } from "./state.js";

// The browser's time zone, an IANA name (Europe/Berlin), or "" when it names none.
function browserZone() {
  try {
    return Intl.DateTimeFormat().resolvedOptions().timeZone || "";
  } catch (_) {
    return "";
  }
}

export async function refreshShifts() {
  const starts = (model.config.shift_starts || []).join(",");
  const base = "/dashboard/shifts?count=3" + (starts ? `&starts=${encodeURIComponent(starts)}` : "");
  // Without a zone name: today's offset for every shift (an hour off for the shifts before a DST change).
  const byOffset = `${base}&tz_offset_min=${-new Date().getTimezoneOffset()}`;
  const zone = browserZone();
  let shifts;
  try {
    shifts = await getLatest("shifts", zone ? `${base}&tz=${encodeURIComponent(zone)}` : byOffset);
  } catch (err) {
    // 422: the service's tz database lacks this zone (a name newer than it); count by the offset instead.
    if (!zone || !/: 422 /.test(String(err && err.message))) throw err;
    shifts = await getLatest("shifts", byOffset);
  }
  if (shifts === null) return;
  model.shifts = shifts;
  renderShifts();
}

function renderShifts() {
  const shifts = (model.shifts && model.shifts.shifts) || [];
  const rows = shifts.map((s) => {
    const notOk = el("td", { class: "num", "data-count": "not-ok", text: String(s.not_ok) });
    setClass(notOk, "is-alarm", s.current && s.not_ok > 0);
    return el(
      "tr",
      { class: s.current ? "is-current" : null, "data-shift": s.current ? "current" : "earlier" },
      el("th", { scope: "row" }, s.current ? el("strong", { text: "Now " }) : null, `${s.start_local} to ${clock(s.end_utc).slice(0, 5)}`),
      el("td", { class: "num", "data-count": "good", text: String(s.good) }),
      notOk,
      el("td", { class: "num", text: s.median_cycle_time_s === null ? "-" : `${num(s.median_cycle_time_s, 2)} s` }),
    );
  });
  $("shifts").replaceChildren(
    rows.length
      ? el(
          "table",
          { class: "data shifts" },
          el("caption", { class: "visually-hidden", text: "Parts per shift, the current shift first" }),
          el("thead", {}, el("tr", {}, ["Shift", "Good", "Not OK", "Takt (median)"].map((h) => el("th", { scope: "col", text: h })))),
          el("tbody", {}, rows),
        )
      : el("p", { class: "muted", text: "No shift counts yet." }),
  );
}
