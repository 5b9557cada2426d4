"""The guards of a sweep on the move (cellctl.cell.sweep), on the twin: what it fits and what it refuses.

Truth: the twin's feedback reports the commanded path, so a reading taken on the sweep's legs has its flange on
the straight lines between the path's corners, and one taken while the flange moved along the beam (timing the
laser) or stood out along it before is up to ``approach_mm`` off them. The feedback's gaps are the twin's own
(``FeedbackFault``: a share of the 4 ms samples lost).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

import cellctl.cell.sweep as sweep_module
from cellctl.bench.accuracy import RunHooks, RunSettings, run_accuracy
from cellctl.bench.cycle_time import with_align_mode
from cellctl.config import load_config
from cellctl.domain import CycleStep
from cellctl.sim.devices import FeedbackFault

ROOT = Path(__file__).resolve().parents[2]


def off_the_legs_mm(points: NDArray[np.float64], corners: list[NDArray[np.float64]]) -> NDArray[np.float64]:
    """(K,) each point's distance (mm) from the polyline through the corners' positions."""
    ends = [np.asarray(T, dtype=float)[:3, 3] for T in corners]
    best = np.full(len(points), np.inf)
    for a, b in zip(ends, ends[1:]):
        u = b - a
        f = np.clip((points - a) @ u / (u @ u), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(points - (a + f[:, None] * u), axis=1))
    return best


def test_the_plane_is_fitted_to_readings_on_the_paths_legs_only_not_to_those_along_the_beam(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    seen: list[tuple[list[Any], Any]] = []
    inner = sweep_module.sweep_path

    async def spy(run: Any, step: CycleStep, corners: list[Any], **kw: Any) -> Any:
        swept = await inner(run, step, corners, **kw)
        if step is CycleStep.ALIGN:
            seen.append((corners, swept))
        return swept

    monkeypatch.setattr(sweep_module, "sweep_path", spy)
    config = with_align_mode(load_config(ROOT / "config" / "sim.toml"), "on_the_fly")
    run = run_accuracy(config, RunSettings(trials=1, seed=2, calibration="oracle", devices="twin"), progress=False, workdir=tmp_path)
    assert run.trials[0].outcome == "done", run.trials[0].reason
    ((corners, swept),) = seen  # the first sweep times the laser: in, out and in along the beam at the first corner
    off = off_the_legs_mm(swept.poses[:, :3, 3], corners)
    assert swept.poses.shape[0] > 100 and float(off.max()) < 0.5, float(off.max())


class LosesSamples(RunHooks):
    """The robot's feedback loses ``drop`` of its samples: every loss leaves an 8 ms gap, none a stale stream."""

    def __init__(self, drop: float) -> None:
        self.drop = drop

    def attach(self, service: Any) -> None:
        service.extras["twin"].robot.feedback_fault = FeedbackFault(drop_fraction=self.drop)


def test_feedback_with_many_gaps_longer_than_allowed_is_refused_not_bridged(tmp_path: Path) -> None:
    # 30 % of the samples lost and no gap above 5 ms allowed: about half the legs' readings fall in a gap
    config = with_align_mode(load_config(ROOT / "config" / "sim.toml"), "on_the_fly", max_feedback_gap_s=0.005)
    run = run_accuracy(config, RunSettings(trials=1, seed=2, calibration="oracle", devices="twin"), progress=False,
                       workdir=tmp_path, hooks=LosesSamples(0.3))  # fmt: skip
    (trial,) = run.trials
    reason = trial.reason or ""
    assert trial.outcome == "failed" and "had a robot pose within 5 ms" in reason and "nothing is fitted to guesses" in reason, reason
