/* cellctl dashboard, commissioning page: the parts of the job panel (the result, the buttons that
   need the operator token, the prompt the job waits at with its answer, the live camera frame) and
   the table of recent jobs. commissioning.js puts the panel together (renderJob). */

import { post, token } from "./api.js";
import { figureList } from "./figures.js";
import { $, el, setClass, showMessage } from "./dom.js";
import { clearImage, showImage, shownUrl } from "./images.js";
import { clock, dateTime, figure, isNum } from "./format.js";
import { ACTIVE, ALARM_JOBS, WARN_JOBS, fresh, liveOf, noteLive, page, shownId, visible } from "./comm-state.js";

const IMAGE_WIDTH = 640;

// -- the job panel's parts ------------------------------------------------------------------------

export function stateCell(tag, state, attrs = {}) {
  const node = el(tag, { ...attrs, text: state });
  setClass(node, "is-alarm", ALARM_JOBS.has(state));
  setClass(node, "is-warn", WARN_JOBS.has(state));
  return node;
}

export function resultParts(job) {
  const out = [];
  if (job.error) {
    const p = el("p", { class: "problems", id: "comm-job-error", text: job.error });
    setClass(p, "is-alarm", ALARM_JOBS.has(job.state));
    setClass(p, "is-warn", WARN_JOBS.has(job.state));
    out.push(p);
  }
  const res = job.result;
  if (res) {
    out.push(el("h3", { text: "Result" }));
    out.push(el("ul", { class: "summary", id: "comm-summary" }, (res.summary || []).map((line) => el("li", { text: line }))));
    if ((res.warnings || []).length) {
      out.push(el("div", { class: "problems is-warn", id: "comm-warnings" }, el("strong", { text: "Warnings:" }), el("ul", {}, res.warnings.map((w) => el("li", { text: w })))));
    }
    const stored = res.stored_version;
    out.push(
      el("p", {
        id: "comm-stored",
        "data-version": stored ?? "",
        text: isNum(stored) ? `Stored as calibration-set version ${stored}.` : "Not stored: the calibration set was not changed.",
      }),
    );
    if ((res.ready_problems || []).length) {
      out.push(el("div", { class: "muted" }, "Still to do before production:", el("ul", {}, res.ready_problems.map((p) => el("li", { text: p })))));
    }
    if (res.quality && Object.keys(res.quality).length) {
      out.push(el("details", {}, el("summary", { text: "Quality figures" }), figureList(res.quality)));
    }
  }
  if (job.dataset) out.push(el("p", { class: "muted small", text: `Dataset: ${job.dataset}` }));
  return out;
}

export function renderJobButtons() {
  const has = Boolean(token());
  const cancel = $("comm-cancel");
  if (cancel) {
    cancel.disabled = !has;
    cancel.title = has ? "Cancel the job: the robot stops at once; the calibration set stays as it is" : "Enter the operator token first";
  }
  for (const b of document.querySelectorAll("#comm-prompt button")) {
    b.disabled = !has || b.dataset.busy === "1";
    b.title = has ? b.dataset.help || "" : "Enter the operator token first";
  }
}

// -- the prompt -----------------------------------------------------------------------------------

export function renderPrompt() {
  const job = page.job;
  const prompt = job ? job.prompt : null;
  const box = $("comm-prompt");
  const ans = page.answered;
  $("comm-prompt-note").textContent =
    ans && job && ans.job_id === job.id
      ? `Prompt "${ans.kind}" answered by ${ans.actor}: ${ans.action}${isNum(ans.value) ? ` ${figure(ans.value)}` : ""} (${clock(ans.at)}).`
      : "";
  if (!prompt) {
    box.hidden = true;
    box.removeAttribute("data-prompt");
    page.promptShown = null;
    $("comm-prompt-body").replaceChildren();
    return;
  }
  box.hidden = false;
  if (page.promptShown === prompt.id) return; // keep what the engineer typed
  page.promptShown = prompt.id;
  box.dataset.prompt = String(prompt.id);
  box.dataset.kind = prompt.kind;
  const parts = [el("p", { class: "prompt-text", id: "comm-prompt-text", text: prompt.text }), el("p", { class: "muted small", text: `${prompt.kind}, asked ${clock(prompt.created_utc)}` })];
  if (prompt.details && Object.keys(prompt.details).length) {
    parts.push(el("details", {}, el("summary", { text: "Details" }), figureList(prompt.details)));
  }
  let input = null;
  if (prompt.value_label) {
    input = el("input", { id: "comm-prompt-value", type: "number", step: "any", min: 0, value: isNum(prompt.default) ? prompt.default : null });
    parts.push(el("p", { class: "value" }, el("label", { for: "comm-prompt-value", text: prompt.value_label }), " ", input));
  }
  const confirm = el("button", {
    type: "button",
    class: "btn",
    id: "comm-prompt-confirm",
    text: "Confirm",
    "data-help": input ? `Confirm with the value given above (${prompt.value_label})` : "Confirm: the job goes on",
    onclick: () => answer(job.id, prompt, input ? "value" : "confirm", input),
  });
  const cancel = el("button", {
    type: "button",
    class: "btn",
    id: "comm-prompt-cancel",
    text: "Cancel",
    "data-help": "Cancel: the job ends cancelled and the calibration set stays as it is",
    onclick: () => answer(job.id, prompt, "cancel", null),
  });
  parts.push(el("div", { class: "prompt-actions" }, confirm, cancel));
  $("comm-prompt-body").replaceChildren(...parts);
  renderJobButtons();
}

async function answer(jobId, prompt, action, input) {
  const body = { action };
  if (action === "value") {
    const v = Number(input.value);
    if (input.value.trim() === "" || !Number.isFinite(v) || v <= 0) {
      showMessage(`${prompt.value_label}: give a positive number (the default is ${figure(prompt.default)}).`, true);
      input.focus();
      return;
    }
    body.value = v;
  }
  const buttons = document.querySelectorAll("#comm-prompt button");
  for (const b of buttons) b.dataset.busy = "1";
  renderJobButtons();
  const done = await post(`/jobs/${jobId}/prompts/${prompt.id}`, `Answer "${prompt.kind}"`, body);
  for (const b of buttons) delete b.dataset.busy;
  if (done) {
    showMessage(`Answered "${prompt.kind}": ${action}.`);
    const l = liveOf(jobId);
    if (!l || !l.prompt || l.prompt.id === prompt.id) noteLive(jobId, { prompt: null }); // unless the next one is open already
    if (page.job && page.job.id === jobId) page.job = fresh(page.job, -1);
    renderPrompt();
  } else {
    renderJobButtons();
  }
}

// -- the live image -------------------------------------------------------------------------------

export function renderImage() {
  const job = page.job;
  const img = $("comm-image");
  const im = page.image;
  if (!job || im.job !== job.id || im.frames === 0) {
    img.hidden = true;
    clearImage(img);
    $("comm-image-caption").textContent = job && ACTIVE.has(job.state) ? "No camera frame from this job yet." : "No camera frame from this job.";
    return;
  }
  if (!visible()) return; // frames load only while the page is shown
  const want = `/jobs/${job.id}/image?width=${IMAGE_WIDTH}&frame=${im.frames}`;
  if (shownUrl(img) !== want) {
    if (im.loading) {
      im.again = true; // one request at a time: the newest frame follows when this one is in
      return;
    }
    im.loading = true;
    img.dataset.frames = String(im.frames);
    showImage(img, want);
    img.alt = `Camera frame ${im.frames} of job ${job.id} (${job.procedure})`;
  }
  $("comm-image-caption").textContent = `Frame ${img.dataset.frames} of job ${job.id}${ACTIVE.has(job.state) ? " (live)" : ""}.`;
}

export function imageSettled(ok) {
  const im = page.image;
  im.loading = false;
  $("comm-image").hidden = !ok;
  if (im.again) {
    im.again = false;
    renderImage();
  }
}

// -- the recent jobs ------------------------------------------------------------------------------

export function renderJobs() {
  const shown = shownId();
  const rows = page.jobs.map((j) => {
    const stored = isNum(j.version_after) ? `v${j.version_after}` : "-";
    const tr = el(
      "tr",
      { class: "clickable" + (shown === j.id ? " is-selected" : ""), "data-job": j.id },
      el("td", {}, el("a", { href: `#/commissioning/${j.id}`, text: `#${j.id}` })),
      el("td", { text: j.procedure }),
      stateCell("td", j.state),
      el("td", { text: j.actor }),
      el("td", { text: dateTime(j.created_utc) }),
      el("td", { text: dateTime(j.finished_utc) }),
      el("td", { text: stored }),
      el("td", { text: j.error || "" }),
    );
    tr.addEventListener("click", (ev) => {
      if (ev.target.tagName !== "A") location.hash = `#/commissioning/${j.id}`;
    });
    return tr;
  });
  $("comm-jobs").tBodies[0].replaceChildren(...(rows.length ? rows : [el("tr", {}, el("td", { colspan: 8, class: "muted", text: "No jobs yet." }))]));
}
