"""PNG plots of the accuracy benchmark in the style of the paper's Figs. 5 and 6.

Fig. 5: displacement deviation in X, Y and Z (mm) per trial; Fig. 6: rotation deviation about X,
Y and Z (deg) per trial. Each panel shows the tolerance band (+-0.5 mm, +-1 deg), the p99 target
(+-0.15) and the paper's largest deviation over its 20 trials; trials that did not install are
marked along the bottom. Needs matplotlib (the optional extra ``bench``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cellctl.bench.accuracy import AccuracyRun
from cellctl.bench.budget import Budget
from cellctl.bench.stats import AXES, PAPER_TRIALS

# Below this fraction of the tolerance the panel zooms in on the deviations.
ZOOM_BELOW = 0.05


class PlotsUnavailable(RuntimeError):
    """matplotlib is not installed."""


def _pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend, or PlotsUnavailable with the fix."""
    try:
        import matplotlib
    except ImportError:
        raise PlotsUnavailable(
            "the plots need matplotlib: pip install 'cellctl[bench]' (or leave out --plots)"
        ) from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def check_plots_available() -> None:
    """Raise PlotsUnavailable (with the fix) when matplotlib is missing."""
    _pyplot()


def _figure(run: AccuracyRun, unit: str, title: str, path: Path) -> Path:
    plt = _pyplot()
    axes = [a for a in AXES if a.unit == unit]
    stats = {s.axis: s for s in run.axes}
    installed = run.installed
    idx = np.array([t.index for t in installed])
    missed = [t.index for t in run.not_installed]
    fig, panels = plt.subplots(len(axes), 1, figsize=(8.0, 2.6 * len(axes)), sharex=True, constrained_layout=True)
    tol = run.tolerance_mm if unit == "mm" else run.tolerance_deg
    many = len(installed) > 60
    for ax, a in zip(panels, axes):
        e = np.array([t.true_error[a.field] for t in installed if t.true_error is not None])
        s = stats[a.label]
        lo, hi = 0.5, max(run.settings.trials, 1) + 0.5
        ax.axhspan(-tol, tol, color="#d8f0d8", zorder=0, label=f"tolerance +-{tol:g} {unit}")
        ax.axhline(tol, color="#3a8a3a", lw=0.8)
        ax.axhline(-tol, color="#3a8a3a", lw=0.8)
        ax.axhline(s.target_p99, color="#c07000", lw=0.8, ls="--", label=f"p99 target +-{s.target_p99:g}")
        ax.axhline(-s.target_p99, color="#c07000", lw=0.8, ls="--")
        if a.paper_max is not None:
            ax.axhline(a.paper_max, color="#7a4cc0", lw=0.8, ls=":", label=f"paper max ({PAPER_TRIALS} trials) {a.paper_max:g}")
            ax.axhline(-a.paper_max, color="#7a4cc0", lw=0.8, ls=":")
        if len(e):
            if many:
                ax.plot(idx, e, ".", ms=2.5, color="#1f4e9c", label="deviation per trial")
            else:
                ax.plot(idx, e, "o-", ms=4, lw=1.0, color="#1f4e9c", label="deviation per trial")
        biggest = float(np.max(np.abs(e))) if len(e) else 0.0
        if biggest >= tol * ZOOM_BELOW:
            top = max(tol * 1.25, biggest * 1.1)
        else:  # the deviations are tiny against the band: zoom in on them, as the paper's panels do
            top = max(biggest * 1.3, 1e-6)
            outside = [f"tolerance +-{tol:g}"] + ([f"p99 target +-{s.target_p99:g}"] if s.target_p99 > top else [])
            ax.text(
                0.01, 0.03, f"zoomed: {' and '.join(outside)} {unit} lie outside this view",
                transform=ax.transAxes, fontsize=7, color="#3a8a3a",
            )  # fmt: skip
        if missed:  # along the bottom of the panel, whatever its scale
            ax.plot(missed, np.full(len(missed), -0.92 * top), "x", color="#c02020", ms=5, label="did not install")
        ax.set_ylim(-top, top)
        ax.set_xlim(lo, hi)
        ax.set_ylabel(f"{a.label} deviation ({unit})")
        ax.set_title(
            f"{a.label}: max |e| {s.max_abs:.3f}, p99 {s.p99_abs:.3f}, mean {s.mean:+.3f}, std {s.std:.3f} {unit}", fontsize=9
        )
        ax.grid(True, lw=0.3, alpha=0.6)
    panels[0].legend(loc="upper right", fontsize=7, ncol=2)
    panels[-1].set_xlabel("trial")
    cal = "calibration from data" if run.settings.calibration == "data" else "true calibrations (oracle)"
    off = "all error sources on" if not run.settings.off else "off: " + ", ".join(run.settings.off)
    fig.suptitle(f"{title}: {run.settings.trials} trials, seed {run.settings.seed}, {cal}, {off}", fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_accuracy_plots(run: AccuracyRun, out_dir: Path) -> list[Path]:
    """Fig. 5 and Fig. 6 of the run as PNG files in ``out_dir``; returns their paths."""
    return [
        _figure(run, "mm", "Displacement deviation (cf. paper Fig. 5)", out_dir / "fig5_displacement.png"),
        _figure(run, "deg", "Rotation deviation (cf. paper Fig. 6)", out_dir / "fig6_rotation.png"),
    ]


def write_budget_plot(budget: Budget, out_dir: Path) -> Path:
    """A bar chart of p99 |error| per axis for each setting of the budget."""
    plt = _pyplot()
    fig, panels = plt.subplots(1, 2, figsize=(11.0, 4.2), constrained_layout=True)
    for ax, unit in zip(panels, ("mm", "deg")):
        axes = [a for a in AXES if a.unit == unit]
        width = 0.8 / max(len(budget.rows), 1)
        x = np.arange(len(axes))
        for k, row in enumerate(budget.rows):
            st = {s.axis: s for s in row.run.axes}
            ax.bar(x + k * width - 0.4 + width / 2, [st[a.label].p99_abs for a in axes], width, label=row.label)
        ax.axhline(0.15, color="#c07000", lw=0.8, ls="--", label="p99 target 0.15")
        ax.set_xticks(x, [a.label for a in axes])
        ax.set_ylabel(f"p99 |error| ({unit})")
        ax.grid(True, axis="y", lw=0.3, alpha=0.6)
    panels[1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    fig.suptitle(f"Error budget ({budget.mode}): {budget.trials} trials per setting, seed {budget.seed}", fontsize=10)
    path = out_dir / "budget.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
