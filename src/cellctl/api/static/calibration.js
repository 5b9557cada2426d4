/* cellctl dashboard: the calibration page: whether the set is ready for production, the current
   set (one row per part for a versioned set) and its versions. The commissioning page shows the
   same versions table. */

import { getJSON } from "./api.js";
import { figureList } from "./figures.js";
import { $, el, setClass } from "./dom.js";
import { DUE_SOON_DAYS, calibrationDue, partDue } from "./caldue.js";
import { dateTime, day } from "./format.js";
import { emit, model } from "./state.js";
import { renderCalibrationTile } from "./status.js";

export async function refreshCalibration() {
  model.calibration = await getJSON("/calibration");
  renderCalibration();
  if (model.status) renderCalibrationTile();
  emit("calibration", model.calibration);
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
      el("td", { "data-due": name, text: p.status === "ok" ? day(partDue(p.calibrated_utc, model.config.calibration_max_age_days)) : "-" }),
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

function renderCalibration() {
  const cal = model.calibration;
  if (!cal) return;
  const problems = cal.problems || [];
  $("cal-problems").replaceChildren(
    problems.length
      ? el("div", { class: "panel problems is-warn", role: "alert" }, el("strong", { text: "Not ready for production:" }), el("ul", {}, problems.map((p) => el("li", { text: p }))))
      : el("p", { class: "panel", text: "Ready for production: the set is complete, valid and in date." }),
  );
  const maxAge = model.config.calibration_max_age_days;
  const due = calibrationDue(cal, maxAge);
  $("cal-due-line").textContent = due
    ? `Due ${day(due.due)} (${due.daysLeft < 0 ? `overdue by ${-due.daysLeft} d` : `in ${due.daysLeft} d`}): ${due.part} is the oldest part; a part older than ${maxAge} days keeps the cell from production.`
    : `No due date: the set has no dated part (a part older than ${maxAge} days keeps the cell from production).`;
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

