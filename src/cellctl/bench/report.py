"""Text reports of the accuracy benchmark and the error budget (pure formatting, no I/O)."""

from __future__ import annotations

from cellctl.bench.accuracy import AccuracyRun
from cellctl.bench.budget import Budget, PartBudget
from cellctl.bench.cells import CellsRun
from cellctl.bench.sources import CALIBRATION_SOURCE, ERROR_SOURCES
from cellctl.bench.stats import AXES, CELLS_TARGET_P99, MEASUREMENT_TARGET_P99, PAPER_TRIALS, SETTLED_MEAN_BAR, TARGET_P99

# What reduces each source's share of the error, for the budget's closing note.
REMEDIES: dict[str, str] = {
    "robot_accuracy": "calibrate the robot (absolute-accuracy compensation), or keep the install move short and "
    "relative to the last measured pose, so the accuracy field cancels as it does between teaching and production",
    "robot_repeatability": "the install move's own scatter is never measured by the cycle: guide the last "
    "millimetres closed-loop (e.g. EGM corrections from a sensor that sees glass and opening), or a more "
    "repeatable final move (same approach direction, fine point, lower speed)",
    "laser_noise": "average several readings per spot, or use more spots",
    "laser_linearity": "keep the spots at the standoff used in teaching, or calibrate the sensor's linearity",
    "image_noise": "average more verification shots, or more light / longer exposure",
    "teach_hand_guiding": "average more hand-guided installs into g_Pos_0 (calibration.procedure.teach."
    "hand_guided_installs; its error shrinks as 1/sqrt(n)), or refine it from measured installs (the paper scores "
    "against the manual install itself, so its figures cannot show this bias)",
    CALIBRATION_SOURCE: "more calibration data (views, poses, spots) and a check of each calibration's residuals; "
    "the laser and hand-eye parts feed the alignment, the nine-point map and template the offsets",
}


def _f(v: float | None, width: int = 8, digits: int = 4, sign: bool = False) -> str:
    if v is None or v != v:
        return "-".rjust(width)
    return f"{v:{'+' if sign else ''}{width}.{digits}f}"


def _sources_line(off: tuple[str, ...]) -> str:
    if not off:
        return "all on"
    on = [s for s in ERROR_SOURCES if s not in off]
    return f"off: {', '.join(off)}; on: {', '.join(on) or 'none'}"


def format_accuracy(run: AccuracyRun) -> str:
    """The per-axis table beside the paper's figures, the counts and the failures."""
    s = run.settings
    c = run.counts()
    ct = run.cycle_time()
    cal = (
        f"from simulated data (calibration set; prepared in {run.calibration_s:.1f} s)"
        if s.calibration == "data"
        else f"the twin's true mountings, taught by the paper's procedure (oracle; {run.calibration_s:.1f} s)"
    )
    ts = "as configured" if s.time_scale is None else f"{s.time_scale:g}"
    lines = [
        f"accuracy: {s.trials} install cycles of the simulated cell at random car-body postures "
        f"({s.config_source}, seed {s.seed}), "
        + ("each requested by a line PLC over Modbus TCP (recipe_id, the register map's handshake)" if s.via == "plc"
           else "through the orchestrator as in production"),
        f"  devices: {'the twin in-process (kind sim)' if s.devices == 'twin' else 'as configured (drivers and their protocol fakes)'}"
        f"; error sources: {_sources_line(s.off)}",
        f"  calibration: {cal}",
        f"  installed {c['installed']}/{c['requested']}; failed {c['failed']}, refused {c['refused']}, "
        f"interrupted {c['interrupted']}, no result {c['timeout']}; within +-{run.tolerance_mm:g} mm and "
        f"+-{run.tolerance_deg:g} deg on all six axes: {c['within_tolerance_all_axes']}/{c['installed']}",
        f"  cycle time on the cell's clock (simulated robot seconds; time scale {ts}): median {_f(ct['median_s'], 0, 2)} s, "
        f"p95 {_f(ct['p95_s'], 0, 2)} s, p99 {_f(ct['p99_s'], 0, 2)} s; shots per cycle median {_f(ct['median_shots'], 0, 0)}, "
        f"max {_f(ct['max_shots'], 0, 0)}; run took {run.wall_s:.0f} s",
        "  median per step: " + (", ".join(f"{n} {v:.2f} s" for n, v in ct["median_step_s"].items() if v >= 0.005) or "-"),
        "",
        f"  axis unit   max|e|     mean      std   p99|e|  target p99      paper max ({PAPER_TRIALS} trials)  tolerance   in tol.",
    ]
    for a in run.axes:
        verdict = "met" if a.p99_met else ("-" if a.n == 0 else "NOT met")
        paper = f"{a.paper_max:g}" if a.paper_max is not None else "not given"
        lines.append(
            f"  {a.axis:4s} {a.unit:4s} {_f(a.max_abs)} {_f(a.mean)} {_f(a.std)} {_f(a.p99_abs)}  "
            f"<= {a.target_p99:g} {verdict:7s}  {paper:>16s}  {'+-' + format(a.tolerance, 'g'):>9s}  "
            f"{a.within_tolerance:>4d}/{a.n}"
        )
    lines += _recipe_lines(run)
    missed = [a.axis for a in run.axes if not a.p99_met]
    lines.append("")
    lines.append(
        f"  p99 target (<= {TARGET_P99['mm']:g} mm on X, Y, Z and <= {TARGET_P99['deg']:g} deg on Rx, Ry, Rz): "
        + ("met on every axis" if not missed else f"NOT met on {', '.join(missed)}")
    )
    if run.not_installed:
        lines.append(f"  cycles that did not install ({len(run.not_installed)}):")
        for t in run.not_installed[:50]:
            lines.append(f"    trial {t.index} (cycle {t.cycle_id}): {t.outcome}: {t.reason}")
        if len(run.not_installed) > 50:
            lines.append(f"    ... and {len(run.not_installed) - 50} more (all in --json)")
    if run.recoveries:
        lines.append(f"  the bench brought the cell back to Execute {run.recoveries} time(s) after a failed cycle")
    for note in run.notes:
        lines.append(f"  note: {note}")
    return "\n".join(lines)


def _recipe_lines(run: AccuracyRun) -> list[str]:
    """p99 |error| per axis of each recipe's installs, and its ratio to the first recipe's (a mix of recipes)."""
    per = run.per_recipe()
    if not per:
        return []
    first = next(iter(per))  # the configuration's first recipe among those run
    lines = ["", "  per recipe: installed, p99|e| per axis (ratio to " + first + "'s)"]
    for name, stats in per.items():
        cells = [f"{a.axis} {_f(a.p99_abs).strip()}" + ("" if name == first else f" ({_ratio(a.p99_abs, b.p99_abs)})")
                 for a, b in zip(stats, per[first], strict=True)]  # fmt: skip
        lines.append(f"  {name:14.14s} {stats[0].n:>4d}  " + ", ".join(cells))
    return lines


def _ratio(a: float, b: float) -> str:
    return f"{a / b:.2f}x" if b > 0 and a == a and b == b else "-"


def format_budget(budget: Budget) -> str:
    """The budget table: p99 |error| per axis for each setting, the RMS each source adds, the dominant one."""
    head = "each source alone on (all others off)" if budget.mode == "alone-on" else "each source alone off (all others on)"
    axes_head = "  ".join(f"{a.label + ' ' + a.unit:>9s}" for a in AXES)
    lines = [
        f"error budget, {head}: {budget.trials} trials per setting, seed {budget.seed} (the same postures and draws)",
        "",
        "p99 |error| per axis:",
        f"  {'setting':36s} {axes_head}  installed",
    ]
    for r in budget.rows:
        vals = "  ".join(_f(s.p99_abs, 9) for s in r.run.axes)
        c = r.run.counts()
        lines.append(f"  {r.label[:36]:36s} {vals}  {c['installed']}/{c['requested']}")
    lines += ["", "bias and spread: mean / std of the signed error per axis:", f"  {'setting':36s} " + "  ".join(
        f"{a.label + ' ' + a.unit:>15s}" for a in AXES
    )]
    for r in budget.rows:
        lines.append(f"  {r.label[:36]:36s} " + "  ".join(f"{s.mean:+8.4f}/{s.std:.4f}"[:15].rjust(15) for s in r.run.axes))
    shares = budget.shares()
    ref = budget.reference.label
    what = f"over '{ref}'" if budget.mode == "alone-on" else f"to '{ref}' (what removing it takes away)"
    lines += ["", f"p99 |error| each source adds {what}:", f"  {'source':36s} {axes_head}"]
    for src, per_axis in shares.items():
        lines.append(f"  {src:36s} " + "  ".join(_f(per_axis[a.label], 9) for a in AXES))
    dom = budget.dominant()
    lines += ["", "dominant source per axis:"]
    for a in AXES:
        lines.append(f"  {a.label:3s} {dom[a.label] or 'none (the floor: the method itself)'}")
    leaders = sorted({d for d in dom.values() if d is not None})
    if leaders:
        lines += ["", "what would reduce the dominant sources:"]
        for src in leaders:
            lines.append(f"  {src}: {REMEDIES.get(src, '-')}")
    for n in budget.notes:
        lines.append(f"note: {n}")
    return "\n".join(lines)


# -- many cells ------------------------------------------------------------------------------------


def _seeds(seeds: list[int]) -> str:
    return f"seed {seeds[0]}" if len(seeds) == 1 else f"seeds {seeds[0]}-{seeds[-1]}"


def _loop_word(loop: str) -> str:
    return loop if loop == "as configured" else f"loop {loop}"


def format_cells(run: CellsRun) -> str:
    """Pooled figures (loops side by side), per-cell rows, the settled means, the inspection's error, the drift."""
    s = run.settings
    seeds = _seeds(list(s.seeds))
    cal = "each cell's own calibration set, commissioned from its own simulated data" if s.calibration == "data" else "the twin's true mountings (oracle)"
    lines = [
        f"accuracy over {s.cells} simulated cell(s) ({seeds}) x {s.trials} install cycles each ({s.config_source}); "
        f"{' and '.join(_loop_word(x) for x in run.loops)}",
        f"  calibration: {cal}; error sources: {_sources_line(s.off)}; run took {run.wall_s:.0f} s",
        f"  tolerance +-{run.tolerance_mm:g} mm, +-{run.tolerance_deg:g} deg; bars: pooled p99 <= {CELLS_TARGET_P99['mm']:g} mm "
        f"and <= {CELLS_TARGET_P99['deg']:g} deg; each cell's mean error after its first {s.settle} cycles within "
        f"+-{SETTLED_MEAN_BAR['mm']:g} mm (X, Y, Z); inspection p99 <= {MEASUREMENT_TARGET_P99['mm']:g} mm, "
        f"<= {MEASUREMENT_TARGET_P99['deg']:g} deg",
    ]
    lines += [f"  note: {n}" for n in run.notes]
    # Pooled, loops side by side.
    heads = "   ".join(f"{_loop_word(x) + ': max|e|    mean     std  p99|e|':>38s}" for x in run.loops)
    lines += ["", "pooled over the cells (every install of every cell):", f"  axis unit {heads}   bar p99"]
    pooled = {x: run.pooled(x) for x in run.loops}
    for j, a in enumerate(AXES):
        cols = []
        for x in run.loops:
            st = pooled[x][j]
            verdict = "" if st.n == 0 else (" ok" if st.p99_met else " NO")
            cols.append(f"{_f(st.max_abs)}{_f(st.mean)}{_f(st.std)}{_f(st.p99_abs)}{verdict:3s}".rjust(38))
        lines.append(f"  {a.label:4s} {a.unit:4s} {'   '.join(cols)}   <= {pooled[run.loops[0]][j].target_p99:g}")
    counts = "; ".join(
        f"{_loop_word(x)}: installed {sum(len(r.errors()) for r in run.runs(x))}/{s.cells * s.trials}" for x in run.loops
    )
    lines.append(f"  {counts}")
    # Per cell.
    lines += ["", "per cell: mean / std / p99 |e| per axis (mm; deg):"]
    lines.append(f"  {'seed':>5s} {'loop':13s} {'inst.':>5s}  " + "  ".join(f"{a.label + ' mean   std   p99':>22s}" for a in AXES))
    for c in run.cells:
        for x, r in c.items():
            cols = "  ".join(f"{st.mean:+8.4f}{st.std:7.4f}{st.p99_abs:7.4f}" if st.n else f"{'-':>22s}" for st in r.axes())
            lines.append(f"  {r.seed:5d} {_loop_word(x):13s} {len(r.errors()):5d}  {cols}")
    lines += _settled_lines(run) + _inspection_lines(run) + _loop_lines(run) + _drift_lines(run)
    return "\n".join(lines)


def _loop_lines(run: CellsRun) -> list[str]:
    states = [(r, r.loop_state()) for c in run.cells for r in c.values()]
    if not any(st for _, st in states):
        return ["", "the closed loop: no cycle record carries result['spc'] (no loop in this build, or it never ran)"]
    fields = [a.field for a in AXES]
    lines = [
        "",
        "the closed loop after each cell's last cycle: applied offset (estimate) per axis, samples, drifting axes:",
        f"  {'seed':>5s} {'loop':13s} " + " ".join(f"{a.label + ' ' + a.unit:>17s}" for a in AXES) + "  samples  drifting",
    ]
    for r, st in states:
        if not st:
            lines.append(f"  {r.seed:5d} {_loop_word(r.loop):13s} no loop state recorded")
            continue
        applied, est = st.get("applied_offset") or {}, st.get("estimate") or {}
        cols = " ".join(f"{_f(applied.get(f), 7, sign=True)} ({_f(est.get(f), 7, sign=True)})" for f in fields)
        drifting = ", ".join(st.get("drifting_axes") or []) or "none"
        lines.append(f"  {r.seed:5d} {_loop_word(r.loop):13s} {cols} {st.get('samples', '-')!s:>8s}  {drifting}")
    return lines


def _settled_lines(run: CellsRun) -> list[str]:
    s = run.settings
    bar = SETTLED_MEAN_BAR["mm"]
    lines = [
        "",
        f"mean error after each cell's first {s.settle} cycles (the bar: within +-{bar:g} mm on X, Y, Z):",
        f"  {'seed':>5s} {'loop':13s} {'n':>4s} " + " ".join(f"{a.label + ' ' + a.unit:>9s}" for a in AXES) + "  bar",
    ]
    held = {x: 0 for x in run.loops}
    for c in run.cells:
        for x, r in c.items():
            m = r.settled_mean(s.settle)
            n = sum(1 for t in r.run.installed if t.index > s.settle)
            miss = [a.label for a in AXES if a.unit == "mm" and not abs(m[a.label]) <= bar]
            held[x] += n > 0 and not miss
            verdict = "- (no cycles after the settling)" if n == 0 else ("met" if not miss else f"NOT met ({', '.join(miss)})")
            lines.append(f"  {r.seed:5d} {_loop_word(x):13s} {n:4d} " + " ".join(_f(m[a.label], 9, sign=True) for a in AXES) + f"  {verdict}")
    lines.append("  cells within the bar: " + "; ".join(f"{_loop_word(x)} {held[x]}/{len(run.runs(x))}" for x in run.loops))
    return lines


def _inspection_lines(run: CellsRun) -> list[str]:
    lines = ["", "the cell's own inspection: measured minus true deviation, p99 |.| over every inspected install:"]
    for x in run.loops:
        n, p99 = run.measurement(x)
        installed = sum(len(r.errors()) for r in run.runs(x))
        if p99 is None:
            lines.append(
                f"  {_loop_word(x)}: no inspection: no cycle record carries result['measured_deviation'] "
                "(the inspection did not run: process.inspect.enabled, or this build has none)"
            )
            continue
        miss = [a.label for a in AXES if not p99[a.label] <= MEASUREMENT_TARGET_P99[a.unit]]
        vals = "  ".join(f"{a.label} {p99[a.label]:.4f}" for a in AXES)
        lines.append(f"  {_loop_word(x)}: inspected {n}/{installed}: {vals}  " + ("met" if not miss else f"NOT met ({', '.join(miss)})"))
    return lines


def _drift_lines(run: CellsRun) -> list[str]:
    from cellctl.bench.cells import DRIFT_ALARM, drift_alarm_code

    s = run.settings
    if s.drift is None and not any(r.drift_alarm() for x in run.loops for r in run.runs(x)):
        return []
    lines = ["", f"drift: {s.drift.describe()}" if s.drift is not None else "drift alarms (no drift injected):"]
    if drift_alarm_code() is None:
        lines.append(f"  this build has no drift alarm (AlarmCode.{DRIFT_ALARM} is missing): only the tolerance is reported")
    lines.append(f"  {'seed':>5s} {'loop':13s} {'drift alarm at cycle':>21s}  {'first true error out of tolerance':34s} alarm first?")
    for c in run.cells:
        for x, r in c.items():
            alarm = r.drift_alarm()
            out = r.first_out_of_tolerance()
            a_txt = "none" if alarm is None else str(alarm["cycle"])
            o_txt = "none" if out is None else f"cycle {out[0]} ({', '.join(out[1])})"
            if out is None:
                first = "yes (no part left it)" if alarm is not None else "no part left it"
            else:
                first = "yes" if alarm is not None and alarm["cycle"] < out[0] else "NO"
            lines.append(f"  {r.seed:5d} {_loop_word(x):13s} {a_txt:>21s}  {o_txt:34s} {first}")
            if alarm is not None:
                lines.append(f"        alarm: {alarm['message'][:150]}")
    return lines


# -- the budget by calibration part ------------------------------------------------------------------


def format_part_budget(budget: PartBudget) -> str:
    """Per axis: the cells' bias, how much each part's swap moves the mean error (RMS over cells), the dominant part."""
    from cellctl.bench.parts import PART_NAMES_FOR_REPORT, PART_ROWS

    rows = [r for r in PART_ROWS if r.key in budget.keys]
    axes_head = "  ".join(f"{a.label + ' ' + a.unit:>9s}" for a in AXES)
    lines = [
        f"budget by calibration part: {len(budget.seeds)} cell(s) ({_seeds(budget.seeds)}), "
        f"{budget.trials} trials per row, the same trials in every row",
        "",
        "rows (each part swapped for the twin's true value):",
    ]
    for r in rows:
        lines.append(f"  {r.key:16s} {r.label}" + (f"; {r.chain}; effect read against '{r.against}'" if r.against else ""))
    lines += ["", "mean error per cell and row:", f"  {'seed':>5s} {'row':16s} {axes_head}"]
    for c in budget.cells:
        for r in rows:
            if r.key in c.rows:
                m = c.mean(r.key)
                lines.append(f"  {c.seed:5d} {r.key:16s} " + "  ".join(f"{m[a.label]:+9.4f}" for a in AXES))
    bias = budget.bias_rms()
    lines += ["", "how much each swap moves a cell's mean error (RMS over cells):", f"  {'':38s} {axes_head}"]
    lines.append(f"  {'the cells bias (as commissioned)':38s} " + "  ".join(_f(bias[a.label], 9) for a in AXES))
    for key, per in budget.rms_effects().items():
        row = next(r for r in rows if r.key == key)
        name = PART_NAMES_FOR_REPORT.get(row.part or "", row.label)
        lines.append(f"  {name[:38]:38s} " + "  ".join(_f(per[a.label], 9) for a in AXES))
    dom = budget.dominant()
    lines += ["", "dominant calibration part per axis (the largest RMS effect):"]
    for a in AXES:
        lines.append(f"  {a.label:3s} {PART_NAMES_FOR_REPORT.get(dom[a.label] or '', 'none')}")
    lines += [f"note: {n}" for n in budget.notes]
    return "\n".join(lines)
