/* cellctl dashboard: the overview page: the last camera image, the install-deviation and
   cycle-time trends, and the filmstrip of recent cycles (not OK ones pinned first). All of it comes
   from GET /dashboard/cycles, the recent cycles digested. */

import { getLatest, thumbUrl } from "./api.js";
import { $, el } from "./dom.js";
import { showImage, shownUrl, tokenImage } from "./images.js";
import { chart, chartWidth } from "./chart.js";
import { clock, isNum } from "./format.js";
import { AXES, NOK_CYCLES, model } from "./state.js";
import { renderPart } from "./status.js";

const TREND_CYCLES = 30;
const FILM_RECENT = 10;
const FILM_PINNED = 6;

export async function refreshDigest() {
  const digest = await getLatest("digest", "/dashboard/cycles?limit=60");
  if (digest === null) return;
  model.digest = digest;
  renderTrends();
  renderFilmstrip();
  renderLastImage();
  renderPart();
}

// -- trends ---------------------------------------------------------------------------------------

export function renderTrends() {
  const tol = model.config.tolerance;
  const sixWidth = chartWidth($("trend-charts"), 3);
  const chronological = model.digest.slice().reverse();
  const installed = chronological.filter((c) => c.state === "done").slice(-TREND_CYCLES);
  const useMeasured = installed.some((c) => c.measured);
  const useTruth = !useMeasured && (model.config.simulation || chronological.some((c) => c.true_error));
  const source = useMeasured ? "measured" : useTruth ? "true_error" : "residual";
  $("h-trends").textContent = useMeasured
    ? "Install deviation: measured after the install"
    : useTruth
      ? "Install deviation: true error (simulated cell)"
      : "Install deviation: verification shot residual";
  $("trend-note").textContent =
    (useMeasured
      ? "The glass against the opening as the cell measured it (gaps in the image, flush by the laser); red: part not OK; " +
        (installed.some((c) => c.true_error) ? "the twin's truth is in each cycle's record; " : "")
      : useTruth
        ? "The twin's truth of the installed glass against the template, "
        : "The last verification shot's offset; dZ, dRx and dRy are set by the laser alignment and not measured by the shot. ") +
    (installed.length ? `last ${installed.length} installed cycle${installed.length === 1 ? "" : "s"}` : "no installed cycle yet") +
    `; each chart's scale follows its data (\u00b1 max * 1.2, written on the axis); grey band: tolerance ` +
    `\u00b1${tol.position_mm} mm, \u00b1${tol.orientation_deg} deg, arrows at the edges when the band is beyond the scale.`;
  const charts = AXES.map((ax) => {
    const band = ax.kind === "position" ? tol.position_mm : tol.orientation_deg;
    const points = installed.map((c) => ({ id: c.id, y: c[source] ? c[source][ax.key] : null, nok: c.part_ok === false }));
    const c = chart({
      title: ax.label,
      unit: ax.unit,
      band,
      points,
      digits: 3,
      width: sixWidth,
      height: 150,
      emptyText: useMeasured || useTruth || installed.length === 0 ? "no installed cycle yet" : "not measured by the verification shot",
    });
    c.dataset.axis = ax.key;
    return c;
  });
  $("trend-charts").replaceChildren(...charts);
  // The takt: the good parts' cycle times (done and not marked not OK: as the shift table's median
  // counts them), the last TREND_CYCLES of them; the other cycles' times in between (a failed
  // cycle's partial time) are drawn hollow and not counted.
  const good = (c) => c.state === "done" && c.part_ok !== false;
  const timed = chronological.filter((c) => isNum(c.cycle_time_s));
  const goodIds = timed.filter(good).map((c) => c.id);
  const since = goodIds.length ? goodIds[Math.max(0, goodIds.length - TREND_CYCLES)] : null;
  const shown = since === null ? timed.slice(-TREND_CYCLES) : timed.filter((c) => c.id >= since);
  const ct = chart({
    title: "Takt (cycle time)",
    unit: "s",
    band: null,
    points: shown.map((c) => ({ id: c.id, y: c.cycle_time_s, nok: !good(c), counted: good(c) })),
    digits: 2,
    emptyText: "no finished cycle yet",
    uncountedNote: "failed or not OK cycles drawn hollow, not counted",
    width: chartWidth($("cycle-time-chart"), 1),
    height: 130,
  });
  ct.dataset.axis = "cycle_time_s";
  $("cycle-time-chart").replaceChildren(ct);
}

// -- the last image and the filmstrip -------------------------------------------------------------

export function renderLastImage() {
  let shown = model.liveImage;
  if (!shown) {
    const c = model.digest.find((d) => d.image);
    if (c) shown = { cycle_id: c.id, name: c.image.name };
  }
  const img = $("last-image");
  const link = $("last-image-link");
  img.hidden = !shown;
  if (!shown) return;
  const src = thumbUrl(shown.cycle_id, shown.name, 640);
  if (shownUrl(img) !== src) {
    showImage(img, src);
    img.alt = `Annotated camera image ${shown.name} of cycle ${shown.cycle_id}, with the vision overlay`;
    img.dataset.cycle = String(shown.cycle_id);
    link.href = `/cycles/${shown.cycle_id}/images/${encodeURIComponent(shown.name)}`;
  }
  const c = model.digest.find((d) => d.id === shown.cycle_id);
  const what = c ? `part ${c.part_id}, ${c.state}` : "running";
  $("last-image-caption").textContent = `Cycle ${shown.cycle_id}, ${shown.name}: ${what}. Select the image for full size.`;
}

function filmItem(c, pinned) {
  const img = c.image
    ? tokenImage(thumbUrl(c.id, c.image.name, 240), { alt: "", width: 240, height: 240 })
    : el("span", { class: "noimg", text: "no image" });
  const btn = el(
    "button",
    {
      type: "button",
      class: "film" + (pinned ? " is-pinned" : ""),
      "data-cycle": c.id,
      "aria-label": `Cycle ${c.id}, part ${c.part_id}, ${c.state}${pinned ? ", not OK, pinned" : ""}: show its detail`,
      onclick: () => {
        location.hash = `#/cycles/${c.id}`;
      },
    },
    img,
    el("span", { class: "cap" }, pinned ? el("span", { class: "pin", text: "NOT OK" }) : null, ` #${c.id} ${c.part_id}`),
    el("span", { class: "cap", text: `${c.state} ${clock(c.finished_at || c.created_at)}` }),
  );
  return el("li", {}, btn);
}

// What a film item shows; the strip is rebuilt only when this changes, so a refresh that brings
// nothing new neither reloads the thumbnails nor swaps a button out from under the operator's click.
const filmKey = (c, pinned) => [c.id, c.part_id, c.state, c.image ? c.image.name : "", c.finished_at || c.created_at, pinned].join("|");
let shownFilm = null;

function renderFilmstrip() {
  const pinned = model.digest.filter((c) => NOK_CYCLES.has(c.state)).slice(0, FILM_PINNED);
  const pinnedIds = new Set(pinned.map((c) => c.id));
  const recent = model.digest.filter((c) => !pinnedIds.has(c.id)).slice(0, FILM_RECENT);
  const key = [...pinned.map((c) => filmKey(c, true)), ...recent.map((c) => filmKey(c, false))].join("\n");
  if (key === shownFilm) return;
  shownFilm = key;
  const items = [...pinned.map((c) => filmItem(c, true)), ...recent.map((c) => filmItem(c, false))];
  $("filmstrip").replaceChildren(...(items.length ? items : [el("li", { class: "muted", text: "No cycles yet." })]));
}

