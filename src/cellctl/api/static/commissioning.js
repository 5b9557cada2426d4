/* cellctl dashboard: the commissioning page (#/commissioning). Calibration, teaching and
   verification run in the service as jobs (POST /jobs); this page starts them, shows the plan of a
   dry run, follows the running job (progress, live camera frame, the prompt it waits at), answers
   prompts and cancels. It uses the helpers app.js puts on window.cellctl (requests with the
   operator token, el(), the event stream, routing); nothing here is loaded from outside the cell. */
"use strict";

(() => {
  const C = window.cellctl;
  if (!C) {
    console.error("commissioning.js needs app.js loaded first");
    return;
  }
  const { $, el, isNum, figure, clock, dateTime, setClass, getJSON, post, showMessage, schedule } = C;

  const JOB_STATES = new Set(["STOPPED", "IDLE"]); // the PackML states a job may start in
  const ACTIVE = new Set(["running", "computing"]);
  const ALARM_JOBS = new Set(["failed"]);
  const WARN_JOBS = new Set(["refused", "interrupted"]);
  const NUMBER_OPTIONS = { views: "board views", poses: "laser poses" };
  const IMAGE_WIDTH = 640;
  const JOBS_LISTED = 20;

  const page = {
    procedures: null, // ProcedureView[] from GET /procedures
    jobs: [], // recent JobViews, newest first
    job: null, // the JobView shown
    running: null, // id of the job the service runs now
    answered: null, // the last answer seen on the event stream: {job_id, kind, action, value, actor}
    promptShown: null, // id of the prompt whose form is on the page (kept while the engineer types)
    image: { job: null, frames: 0, loading: false, again: false },
    planning: false,
    starting: false,
  };
  window.cellctlCommissioning = page;

  const visible = () => C.currentPage().page === "commissioning";

  // The job the page shows: the one named in the address (#/commissioning/7), else the running
  // one, else the newest.
  function shownId() {
    const { page: p, id } = C.currentPage();
    if (p === "commissioning" && id !== null) return id;
    if (page.running !== null) return page.running;
    return page.jobs.length ? page.jobs[0].id : null;
  }

  function seconds(s) {
    if (!isNum(s)) return "-";
    if (s < 90) return `${s.toFixed(0)} s`;
    const m = Math.floor(s / 60);
    return `${m} min ${String(Math.round(s - 60 * m)).padStart(2, "0")} s`;
  }

  // -- data ------------------------------------------------------------------------------------

  async function refreshProcedures() {
    page.procedures = await getJSON("/procedures");
    renderProcedures();
  }

  // What the event stream said last about each job. A record fetched while events came in may be
  // older than they are: what they carry wins over it (see fresh()).
  const LIVE_FIELDS = ["state", "progress", "plan", "error", "dataset", "version_after", "prompt"];
  const live = new Map();
  let seq = 0; // job and prompt events seen

  function noteLive(id, fields) {
    const cur = live.get(id) || {};
    live.delete(id); // re-inserted last: the map keeps the newest few jobs
    live.set(id, Object.assign(cur, fields, { seq: ++seq }));
    while (live.size > 8) live.delete(live.keys().next().value);
  }

  // The record `view`, with what events that came after `mark` said about it.
  function fresh(view, mark) {
    const l = live.get(view.id);
    if (!l || l.seq <= mark) return view;
    const out = { ...view };
    for (const k of LIVE_FIELDS) if (k in l) out[k] = l[k];
    out.running = ACTIVE.has(out.state);
    return out;
  }

  async function refreshJobs() {
    const mark = seq;
    const jobs = await getJSON(`/jobs?limit=${JOBS_LISTED}`);
    page.jobs = jobs.map((j) => fresh(j, mark));
    if (seq === mark) {
      const running = page.jobs.find((j) => j.running);
      page.running = running ? running.id : null;
    }
    renderJobs();
    renderGate();
  }

  async function refreshShown() {
    const id = shownId();
    if (id === null) {
      page.job = null;
      renderJob();
      return;
    }
    const mark = seq;
    let view;
    try {
      view = fresh(await getJSON(`/jobs/${id}`), mark);
    } catch (err) {
      if (shownId() === id) {
        page.job = null;
        renderJob();
        $("comm-job-head").replaceChildren(el("p", { class: "problems is-warn", text: err.message }));
      }
      return;
    }
    if (shownId() !== id) return;
    page.job = view;
    if (view.running) page.running = view.id;
    renderJob();
    renderJobs();
  }

  async function sync() {
    const work = [refreshJobs().then(refreshShown), C.refreshCalibration()];
    if (!page.procedures) work.push(refreshProcedures());
    const results = await Promise.allSettled(work);
    for (const r of results) if (r.status === "rejected") console.warn("commissioning refresh failed:", r.reason);
  }

  // -- procedures: start and dry run ------------------------------------------------------------

  function partStatus(name) {
    const cur = C.model.calibration && C.model.calibration.current;
    const p = cur && cur.parts ? cur.parts[name] : null;
    return p ? p.status : null;
  }

  function optionInputs(proc) {
    const out = [];
    for (const opt of proc.options) {
      const id = `comm-opt-${proc.name}-${opt}`;
      if (NUMBER_OPTIONS[opt]) {
        out.push(
          el("label", { for: id, text: NUMBER_OPTIONS[opt] }),
          el("input", { id, type: "number", min: 1, step: 1, size: 5, inputmode: "numeric", placeholder: "default", "data-option": opt }),
        );
      } else if (opt === "store") {
        out.push(
          el("label", { class: "check" }, el("input", { id, type: "checkbox", checked: true, "data-option": opt }), "store the result"),
        );
      }
    }
    return out;
  }

  function renderProcedures() {
    const procs = page.procedures || [];
    if (!procs.length) {
      $("comm-procedures").replaceChildren(el("p", { class: "muted", text: "The service offers no procedures." }));
      return;
    }
    const rows = procs.map((p) =>
      el(
        "tr",
        { "data-procedure": p.name },
        el("th", { scope: "row" }, p.name, el("br"), el("span", { class: "muted small", text: p.command })),
        el("td", { class: "needs", text: "-" }),
        el("td", {}, el("div", { class: "options" }, optionInputs(p))),
        el(
          "td",
          { class: "actions" },
          el("button", { type: "button", class: "btn btn-small", "data-start": p.name, text: "Start", onclick: () => startJob(p) }),
          el("button", { type: "button", class: "btn btn-small", "data-plan": p.name, text: "Dry run (plan)", onclick: () => planJob(p) }),
        ),
      ),
    );
    $("comm-procedures").replaceChildren(
      el(
        "table",
        { class: "data", id: "comm-proc-table" },
        el("thead", {}, el("tr", {}, ["Procedure", "Needs", "Options", "Run"].map((h) => el("th", { scope: "col", text: h })))),
        el("tbody", {}, rows),
      ),
    );
    renderGate();
  }

  // Why a procedure cannot start now, or null.
  function startBlocked(proc) {
    if (!C.token()) return "enter the operator token first";
    if (page.starting) return "a start is on its way";
    const st = C.model.status;
    if (page.running !== null) return `job ${page.running} is running: one job at a time; wait for it or cancel it`;
    if (st && !JOB_STATES.has(st.state)) {
      return `jobs start in STOPPED or IDLE only; the cell is ${st.state} (${st.state === "ABORTED" ? "send Clear" : "send Stop"} first)`;
    }
    const missing = proc.needs.filter((n) => partStatus(n) !== "ok");
    if (missing.length) return `${proc.name} needs ${missing.join(", ")} calibrated first`;
    return null;
  }

  function renderGate() {
    const st = C.model.status;
    const notes = [];
    if (!C.token()) notes.push("Enter the operator token (above) to start jobs, answer prompts and cancel.");
    if (st && !JOB_STATES.has(st.state)) notes.push(`Jobs start in STOPPED or IDLE only; the cell is ${st.state}.`);
    if (page.running !== null) notes.push(`Job ${page.running} is running; one job runs at a time.`);
    $("comm-gate").textContent = notes.join(" ");
    for (const p of page.procedures || []) {
      const row = document.querySelector(`#comm-proc-table tr[data-procedure="${p.name}"]`);
      if (!row) continue;
      const needs = row.querySelector(".needs");
      needs.replaceChildren(
        ...(p.needs.length
          ? [p.needs.map((n) => `${n} ${partStatus(n) || "missing"}`).join(", ")]
          : ["nothing"]),
      );
      const start = row.querySelector("[data-start]");
      const why = startBlocked(p);
      start.disabled = why !== null;
      start.title = why ? `Cannot start: ${why}` : `Start ${p.name}: the robot moves after you confirm the plan`;
      row.querySelector("[data-plan]").disabled = page.planning;
    }
    renderJobButtons();
  }

  function gatherOptions(proc) {
    const options = {};
    for (const input of document.querySelectorAll(`#comm-proc-table tr[data-procedure="${proc.name}"] [data-option]`)) {
      const opt = input.dataset.option;
      if (input.type === "checkbox") {
        if (!input.checked) options[opt] = false;
      } else if (input.value.trim() !== "") {
        const v = Number(input.value);
        if (!Number.isInteger(v) || v <= 0) throw new Error(`${NUMBER_OPTIONS[opt] || opt}: give a whole number, or leave it empty for the default`);
        options[opt] = v;
      }
    }
    return options;
  }

  async function startJob(proc) {
    let options;
    try {
      options = gatherOptions(proc);
    } catch (err) {
      showMessage(`Start ${proc.name}: ${err.message}.`, true);
      return;
    }
    const mark = seq;
    page.starting = true;
    renderGate();
    let created;
    try {
      created = await post("/jobs", `Start ${proc.name}`, { procedure: proc.name, options });
    } finally {
      page.starting = false;
      renderGate();
    }
    if (!created) return;
    const view = fresh(created, mark);
    showMessage(`Job ${view.id} (${proc.name}) started; it shows its plan and waits for your confirmation before the first move.`);
    // The job's first events (even its first prompts) may have come before this answer.
    if (view.running) page.running = view.id;
    page.job = view;
    if (C.currentPage().id !== null) location.hash = "#/commissioning"; // follow the new job
    renderJob();
    renderGate();
    schedule("comm-job", refreshShown, 0);
    schedule("comm-jobs", refreshJobs, 0);
  }

  async function planJob(proc) {
    let options;
    try {
      options = gatherOptions(proc);
    } catch (err) {
      showMessage(`Plan ${proc.name}: ${err.message}.`, true);
      return;
    }
    page.planning = true;
    renderGate();
    try {
      const plan = await post("/jobs/plan", `Plan ${proc.name}`, { procedure: proc.name, options }, { open: true });
      if (plan) renderPlan(plan);
    } finally {
      page.planning = false;
      renderGate();
    }
  }

  function renderPlan(plan) {
    const rot = plan.rotation || {};
    const rows = [
      ["Poses", String(plan.poses)],
      ["Robot time", `about ${seconds(plan.estimated_robot_time_s)} at up to ${figure(plan.speed_mm_s)} mm/s, ${figure(plan.speed_deg_s)} deg/s`],
      ["Rotation", Object.entries(rot).map(([k, v]) => `${k} ${figure(v)}`).join(", ") || "-"],
      ["Dropped", plan.dropped.length ? `${plan.dropped.length}: ${plan.dropped.slice(0, 3).join("; ")}${plan.dropped.length > 3 ? "; ..." : ""}` : "none"],
    ];
    if (plan.first_pose) {
      const fp = plan.first_pose;
      const at = Array.isArray(fp.position_mm) ? fp.position_mm.map((v) => v.toFixed(0)).join(", ") : "-";
      rows.push(["First pose", `${fp.label || ""} (${at}) mm`]);
    }
    $("comm-plan").replaceChildren(
      el(
        "div",
        { class: "plan", "data-procedure": plan.procedure },
        el("h3", { text: `Plan for ${plan.procedure} (dry run: nothing moved)` }),
        el("dl", { class: "kv" }, rows.map(([k, v]) => [el("dt", { text: k }), el("dd", { text: v })])),
      ),
    );
  }

  // -- the job ---------------------------------------------------------------------------------

  function stateCell(tag, state, attrs = {}) {
    const node = el(tag, { ...attrs, text: state });
    setClass(node, "is-alarm", ALARM_JOBS.has(state));
    setClass(node, "is-warn", WARN_JOBS.has(state));
    return node;
  }

  function renderJob() {
    const job = page.job;
    const box = $("comm-job");
    const note = $("comm-running-note");
    const other = page.running !== null && (!job || job.id !== page.running);
    note.hidden = !other;
    note.replaceChildren(...(other ? [`Job ${page.running} is running: `, el("a", { href: "#/commissioning", text: "show it" }), "."] : []));
    if (!job) {
      box.removeAttribute("data-job");
      box.removeAttribute("data-state");
      $("comm-job-head").replaceChildren(el("p", { class: "muted", text: "No commissioning job yet." }));
      $("comm-job-result").replaceChildren();
      $("comm-job-facts").replaceChildren();
      renderPrompt();
      renderImage();
      return;
    }
    box.dataset.job = String(job.id);
    box.dataset.state = job.state;
    const prog = job.progress || {};
    const total = isNum(prog.total) ? prog.total : null;
    const done = isNum(prog.done) ? prog.done : 0;
    const bar = el("progress", { id: "comm-progress", max: total || 1, value: total ? done : 0, "aria-labelledby": "comm-progress-text" });
    const progressText = total ? `${done} / ${total}` : job.state === "running" ? "not started" : "-";
    const plan = job.plan;
    const now = [`Step: ${prog.message || "-"}`, `elapsed ${seconds(prog.elapsed_s)}`];
    if (ACTIVE.has(job.state)) now.push(`time left ${seconds(prog.time_left_s)}`);
    const head = [
      el("p", { class: "job-title" }, el("strong", { text: `Job ${job.id}: ${job.procedure} ` }), stateCell("span", job.state, { class: "job-state", id: "comm-job-state" })),
      el(
        "div",
        { class: "progress" },
        bar,
        el("span", { id: "comm-progress-text", text: `Progress ${progressText}` }),
        job.state === "computing" ? el("span", { text: " computing the result" }) : null,
      ),
      prog.message || ACTIVE.has(job.state) ? el("p", { class: "job-live", id: "comm-job-live", text: now.join(", ") }) : null,
      el("button", { type: "button", class: "btn", id: "comm-cancel", text: "Cancel job", hidden: !job.running, onclick: () => cancelJob(job.id) }),
    ];
    $("comm-job-head").replaceChildren(...head.filter(Boolean));
    $("comm-job-facts").replaceChildren(
      el(
        "dl",
        { class: "kv" },
        [
          ["Plan", plan ? `${plan.poses} poses, about ${seconds(plan.estimated_robot_time_s)} of robot time${plan.dropped && plan.dropped.length ? `, ${plan.dropped.length} dropped` : ""}` : "-"],
          ["Started by", `${job.actor} via ${job.source}, ${dateTime(job.created_utc)}`],
          ["Finished", dateTime(job.finished_utc)],
          ["Options", Object.keys(job.options || {}).length ? Object.entries(job.options).map(([k, v]) => `${k} ${v}`).join(", ") : "defaults"],
        ].map(([k, v]) => [el("dt", { text: k }), el("dd", { text: v })]),
      ),
    );
    $("comm-job-result").replaceChildren(...resultParts(job));
    renderPrompt();
    renderJobButtons();
    renderImage();
  }

  function resultParts(job) {
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
        out.push(el("details", {}, el("summary", { text: "Quality figures" }), C.kvList(res.quality)));
      }
    }
    if (job.dataset) out.push(el("p", { class: "muted small", text: `Dataset: ${job.dataset}` }));
    return out;
  }

  function renderJobButtons() {
    const has = Boolean(C.token());
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

  async function cancelJob(id) {
    const btn = $("comm-cancel");
    if (btn) btn.disabled = true;
    const mark = seq;
    const answer = await post(`/jobs/${id}/cancel`, `Cancel job ${id}`);
    const view = answer ? fresh(answer, mark) : null;
    if (view) {
      showMessage(`Job ${id} ${view.state}${view.error ? `: ${view.error}` : ""}.`);
      if (page.job && page.job.id === id) page.job = view;
      if (page.running === id && !view.running) page.running = null;
      renderJob();
      renderGate();
      schedule("comm-jobs", refreshJobs, 0);
    } else {
      renderJobButtons();
    }
  }

  // -- the prompt ------------------------------------------------------------------------------

  function renderPrompt() {
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
      parts.push(el("details", {}, el("summary", { text: "Details" }), C.kvList(prompt.details)));
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
      const l = live.get(jobId);
      if (!l || !l.prompt || l.prompt.id === prompt.id) noteLive(jobId, { prompt: null }); // unless the next one is open already
      if (page.job && page.job.id === jobId) page.job = fresh(page.job, -1);
      renderPrompt();
    } else {
      renderJobButtons();
    }
  }

  // -- the live image --------------------------------------------------------------------------

  function renderImage() {
    const job = page.job;
    const img = $("comm-image");
    const im = page.image;
    if (!job || im.job !== job.id || im.frames === 0) {
      img.hidden = true;
      img.removeAttribute("src");
      $("comm-image-caption").textContent = job && ACTIVE.has(job.state) ? "No camera frame from this job yet." : "No camera frame from this job.";
      return;
    }
    if (!visible()) return; // frames load only while the page is shown
    const want = `/jobs/${job.id}/image?width=${IMAGE_WIDTH}&frame=${im.frames}`;
    if (img.getAttribute("src") !== want) {
      if (im.loading) {
        im.again = true; // one request at a time: the newest frame follows when this one is in
        return;
      }
      im.loading = true;
      img.dataset.frames = String(im.frames);
      img.src = want;
      img.alt = `Camera frame ${im.frames} of job ${job.id} (${job.procedure})`;
    }
    $("comm-image-caption").textContent = `Frame ${img.dataset.frames} of job ${job.id}${ACTIVE.has(job.state) ? " (live)" : ""}.`;
  }

  function imageSettled(ok) {
    const im = page.image;
    im.loading = false;
    $("comm-image").hidden = !ok;
    if (im.again) {
      im.again = false;
      renderImage();
    }
  }

  // -- live updates ----------------------------------------------------------------------------

  function onJob(data) {
    const id = data.job_id;
    const active = ACTIVE.has(data.state);
    const fields = { state: data.state, error: data.error, dataset: data.dataset, version_after: data.version_after };
    if (data.progress && Object.keys(data.progress).length) fields.progress = data.progress;
    if (data.plan) fields.plan = data.plan;
    if (!active) fields.prompt = null;
    noteLive(id, fields);
    if (active) page.running = id;
    else if (page.running === id) page.running = null;
    const job = page.job;
    if (job && job.id === id) {
      page.job = fresh(job, -1);
      renderJob();
      if (job.state !== data.state && visible()) schedule("comm-job", refreshShown, 50); // the result comes with the record
    } else if (shownId() === id && visible()) {
      schedule("comm-job", refreshShown, 50);
    }
    const listed = page.jobs.find((j) => j.id === id);
    if ((!listed || listed.state !== data.state) && visible()) schedule("comm-jobs", refreshJobs, 200);
    if (!active) schedule("calibration", C.refreshCalibration, 200);
    renderGate();
  }

  function onPrompt(data) {
    const id = data.job_id;
    const l = live.get(id);
    if (data.open) {
      noteLive(id, { prompt: data.prompt });
    } else {
      const a = data.answer; // null: the prompt closed unanswered because its job ended
      page.answered = a
        ? { job_id: id, kind: data.prompt.kind, action: a.action, value: a.value, actor: a.actor || "unknown", at: new Date().toISOString() }
        : { job_id: id, kind: data.prompt.kind, action: "closed unanswered (the job ended)", value: null, actor: "nobody", at: new Date().toISOString() };
      const known = l && "prompt" in l ? l.prompt : data.prompt;
      noteLive(id, known && known.id !== data.prompt.id ? {} : { prompt: null });
    }
    if (page.job && page.job.id === id) {
      page.job = fresh(page.job, -1);
      renderPrompt();
    } else if (shownId() === id && visible()) {
      schedule("comm-job", refreshShown, 0);
    }
  }

  C.on("event", (kind, data) => {
    switch (kind) {
      case "status": {
        const id = data.job ? data.job.id : null;
        if (id !== page.running) {
          page.running = id;
          if (visible()) {
            schedule("comm-jobs", refreshJobs, 0);
            schedule("comm-job", refreshShown, 0);
          }
        }
        renderGate();
        break;
      }
      case "state":
        renderGate();
        break;
      case "job":
        onJob(data);
        break;
      case "prompt":
        onPrompt(data);
        break;
      case "job_image":
        page.image = { ...page.image, job: data.job_id, frames: data.frames };
        if (page.job && page.job.id === data.job_id) renderImage();
        break;
      default:
        break;
    }
  });
  C.on("route", (p) => {
    if (p === "commissioning") schedule("comm-sync", sync, 0);
  });
  C.on("refresh", (p) => (p.page === "commissioning" ? sync() : null));
  C.on("token", () => renderGate());
  C.on("calibration", (cal) => {
    $("comm-versions").replaceChildren(C.versionsTable(cal.versions || [], cal.current ? cal.current.version : null));
    renderGate();
  });

  function renderJobs() {
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

  document.addEventListener("DOMContentLoaded", () => {
    const img = $("comm-image");
    img.addEventListener("load", () => imageSettled(true));
    img.addEventListener("error", () => imageSettled(false));
  });
})();
