/* cellctl dashboard: the calibration page: whether the set is ready for production (for every
   recipe, each not-ready one named with its problems), when it falls due (the parts' own expiry),
   the current set (one row per part for a versioned set) and its versions. The commissioning page
   shows the same versions table. The page is read again when the service's verdict changes (app.js,
   from the status event) and when a shown due time passes (here). */

import { getJSON } from "./api.js";
import { figureList } from "./figures.js";
import { $, el, setClass } from "./dom.js";
import { DUE_SOON_DAYS, calibrationDue, dueIn, nextExpiryMs, partDue } from "./caldue.js";
import { noteServiceTime, serviceNow } from "./clock.js";
import { readiness } from "./calready.js";
import { dateTime } from "./format.js";
import { emit, model, schedule } from "./state.js";
import { renderCalibrationTile } from "./status.js";

const RECHECK_MAX_MS = 6 * 3600e3; // the due texts ("in 5 h") are brought up to date at least this often
let dueTimer = null;

export async function refreshCalibration() {
  const sent = Date.now();
  model.calibration = await getJSON("/calibration");
  noteServiceTime(model.calibration.now_utc, sent, Date.now());
  renderCalibration();
  if (model.status) renderCalibrationTile();
  emit("calibration", model.calibration);
  armDueTimer();
}

// Read the set again a second after the next part's expiry (the service's check is `now >= expiry`).
function armDueTimer() {
  clearTimeout(dueTimer);
  const ms = nextExpiryMs(model.calibration, serviceNow());
  dueTimer = setTimeout(() => schedule("calibration", refreshCalibration, 0), Math.min(ms === null ? RECHECK_MAX_MS : ms + 1000, RECHECK_MAX_MS));
}

// Each recipe: whether its own teaching is done and whether its cycles would find the calibration ready.
function recipesTable(recipes) {
  const names = Object.keys(recipes || {});
  if (!names.length) return null;
  const cell = (ok, yes, no) => {
    const td = el("td", { text: ok ? yes : no });
    setClass(td, "is-warn", !ok);
    return td;
  };
  return el(
    "table",
    { class: "data", id: "cal-recipes" },
    el("thead", {}, el("tr", {}, ["Recipe", "Teaching", "Production"].map((h) => el("th", { scope: "col", text: h })))),
    el("tbody", {}, names.map((n) => el("tr", { "data-recipe": n }, el("th", { scope: "row", text: n }),
      cell(recipes[n].taught, "taught", "not taught"), cell(recipes[n].ready, "ready", "not ready")))),
  );
}

function calibrationCurrent(current) {
  if (!current || !Object.keys(current).length) return el("p", { class: "muted", text: "No calibration set loaded." });
  const { recipes, ...withoutRecipes } = current;
  const parts = current.parts;
  if (!parts || typeof parts !== "object") return el("div", { class: "panel" }, figureList(withoutRecipes), recipesTable(recipes));
  // The versioned calibration set: one row per part with its status, date, method and quality.
  const { parts: _omit, ...rest } = withoutRecipes;
  const names = Object.keys(parts);
  const rows = names.map((name) => {
    const p = parts[name];
    if (!p) {
      const missing = el("td", { text: "missing" });
      setClass(missing, "is-warn", true);
      return el("tr", { "data-part": name }, el("th", { scope: "row", text: name }), missing, ["-", "-", "-", "-"].map((t) => el("td", { text: t })));
    }
    const status = el("td", { text: p.status || "-" });
    setClass(status, "is-alarm", p.status === "failed");
    return el(
      "tr",
      { "data-part": name },
      el("th", { scope: "row", text: name }),
      status,
      el("td", { text: dateTime(p.calibrated_utc) }),
      el("td", { "data-due": name, text: p.status === "ok" && partDue(p) ? dateTime(partDue(p)) : "-" }),
      el("td", { text: p.method || "-" }),
      el("td", {}, p.quality && Object.keys(p.quality).length ? figureList(p.quality) : "-", p.failure ? el("p", { text: p.failure }) : null),
    );
  });
  return el(
    "div",
    { class: "panel" },
    figureList(rest),
    names.length
      ? el(
          "table",
          { class: "data", id: "cal-parts" },
          el("thead", {}, el("tr", {}, ["Part", "Status", "Calibrated", "Due", "Method", "Quality figures"].map((h) => el("th", { scope: "col", text: h })))),
          el("tbody", {}, rows),
        )
      : el("p", { class: "muted", text: "The set has no parts yet." }),
    recipesTable(recipes),
  );
}

// Whether the set lets every recipe go into production; the recipes that may not run, each with its
// problems (each line names the command that mends it).
function readinessPanel(r) {
  const li = (line) => el("li", { text: line });
  if (r.ready) {
    const which = r.names.length > 1 ? `every recipe (${r.names.join(", ")}); ` : "";
    return el("p", { class: "panel", "data-ready": "all", text: `Ready for production: ${which}the set is complete, valid and in date.` });
  }
  const every = r.names.length > 1 && r.readyNames.length === 0;
  const out = [];
  if (r.shared.length) {
    out.push(el("strong", { text: every ? "Not ready for production (no recipe may run):" : "Not ready for production:" }));
    out.push(el("ul", { "data-problems": "shared" }, r.shared.map(li)));
  }
  for (const [n, lines] of Object.entries(r.byRecipe)) {
    if (lines && !lines.length) continue; // only the lines above
    const head = `Recipe ${n}: not ready for production${lines ? ":" : " (the service gave no reason)."}`;
    out.push(el("div", { "data-recipe-problems": n }, el("strong", { text: head }), lines ? el("ul", {}, lines.map(li)) : null));
  }
  if (r.readyNames.length) out.push(el("p", { "data-ready": "some", text: `Ready for production: ${r.readyNames.join(", ")}.` }));
  return el("div", { class: "panel problems is-warn", role: "alert" }, out);
}

function renderCalibration() {
  const cal = model.calibration;
  if (!cal) return;
  const r = readiness(cal.problems || [], (cal.current && cal.current.recipes) || {});
  $("cal-problems").replaceChildren(readinessPanel(r));
  const due = calibrationDue(cal, serviceNow());
  const parts = Object.values((cal.current && cal.current.parts) || {}).filter((p) => p);
  $("cal-due-line").textContent = due
    ? `Due ${dateTime(due.due)} (${dueIn(due)}): ${due.part} expires first; an expired part keeps the cell from production.`
    : parts.some((p) => p.status === "ok")
      ? "No due date: the service states no expiry for the set's parts."
      : parts.length
        ? "No due date: no part of the set is ok (a failed or missing part keeps the cell from production)."
        : "No due date: the set has no dated part.";
  setClass($("cal-due-line"), "is-warn", due && due.daysLeft < DUE_SOON_DAYS);
  $("cal-current").replaceChildren(calibrationCurrent(cal.current));
  $("cal-history").replaceChildren(versionsTable(cal.versions || [], cal.current ? cal.current.version : null));
}

// The calibration set's versions, newest first: each part's status in that version.
export function versionsTable(versions, currentVersion) {
  if (!versions.length) return el("p", { class: "muted", text: "No calibration-set version stored yet." });
  const names = [...new Set(versions.flatMap((v) => Object.keys(v.parts || {})))];
  const rows = versions.slice().reverse().map((v) => {
    const isCurrent = v.version === currentVersion;
    const cells = names.map((n) => {
      const st = (v.parts || {})[n];
      const td = el("td", { text: st || "-", "data-part": n });
      setClass(td, "is-alarm", isCurrent && st === "failed"); // colour only what is in use now
      return td;
    });
    return el(
      "tr",
      { "data-version": v.version, class: isCurrent ? "is-current" : null },
      el("th", { scope: "row" }, `v${v.version}`, isCurrent ? el("strong", { text: " (in use)" }) : null),
      el("td", { text: dateTime(v.created_utc) }),
      el("td", { text: v.note || "-" }),
      cells,
    );
  });
  return el(
    "table",
    { class: "data versions" },
    el("caption", { class: "visually-hidden", text: "Calibration-set versions, newest first" }),
    el("thead", {}, el("tr", {}, ["Version", "Created", "Note", ...names].map((h) => el("th", { scope: "col", text: h })))),
    el("tbody", {}, rows),
  );
}

