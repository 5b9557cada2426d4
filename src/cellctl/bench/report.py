"""Text reports of the accuracy benchmark and the error budget (pure formatting, no I/O)."""

from __future__ import annotations

from cellctl.bench.accuracy import AccuracyRun
from cellctl.bench.budget import Budget
from cellctl.bench.sources import CALIBRATION_SOURCE, ERROR_SOURCES
from cellctl.bench.stats import AXES, PAPER_TRIALS, TARGET_P99

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


def _f(v: float | None, width: int = 8, digits: int = 4) -> str:
    if v is None or v != v:
        return "-".rjust(width)
    return f"{v:{width}.{digits}f}"


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
        f"({s.config_source}, seed {s.seed}), through the orchestrator as in production",
        f"  devices: {'the twin in-process (kind sim)' if s.devices == 'twin' else 'as configured (drivers and their protocol fakes)'}"
        f"; error sources: {_sources_line(s.off)}",
        f"  calibration: {cal}",
        f"  installed {c['installed']}/{c['requested']}; failed {c['failed']}, refused {c['refused']}, "
        f"interrupted {c['interrupted']}, no result {c['timeout']}; within +-{run.tolerance_mm:g} mm and "
        f"+-{run.tolerance_deg:g} deg on all six axes: {c['within_tolerance_all_axes']}/{c['installed']}",
        f"  cycle time (simulated time scale {ts}): median {_f(ct['median_s'], 0, 3)} s, p99 {_f(ct['p99_s'], 0, 3)} s; "
        f"shots per cycle median {_f(ct['median_shots'], 0, 0)}, max {_f(ct['max_shots'], 0, 0)}; run took {run.wall_s:.0f} s",
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
