"""Door window (arc corner): a first shot taken with the relaxed first-shot limits may be off by more than one
verification step, so the move after verification shot 1 is held to the first correction's limits.
Truth: the twin's posture of the car body (its turn about T's z) and the install's true error.

Seed 7, cycle 2, pivot "opening_centre" (a documented [sim.world] option): the car body is truly turned -1.34 deg,
shot 0 (its arc's centre off the image) measured -0.79 deg, and the move after shot 1 (0.55 deg) was refused
against max_verify_step_deg = 0.5 although the car body lies inside the posture range.
"""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import numpy as np
from shared_support import door_window_first

from cellctl.bench.accuracy import RunHooks, RunSettings, run_accuracy
from cellctl.config import CellConfig
from cellctl.domain import CycleStep
from cellctl.geometry.pose import invert_pose
from cellctl.geometry.rotation import matrix_to_xyz_fixed

def _door_window_first(pivot: str) -> CellConfig:
    return door_window_first(lambda data: data["sim"]["world"].update(posture_pivot=pivot))


class TrueTurn(RunHooks):
    """The car body's true turn about T's z (deg) in each cycle, from the twin's placement."""

    def __init__(self) -> None:
        self.rz_deg: list[float] = []

    def attach(self, service):  # type: ignore[no-untyped-def]
        self.cell = service.extras["twin"].cell

    def after_cycle(self, k, service, trial):  # type: ignore[no-untyped-def]
        E = invert_pose(self.cell.world_config.T_B_T_nominal()) @ self.cell.world().T_B_T
        self.rz_deg.append(float(np.degrees(matrix_to_xyz_fixed(E[:3, :3])[0])))


def test_a_first_arc_shot_off_by_more_than_a_verification_step_still_installs_within_tolerance(tmp_path: Path) -> None:
    hooks = TrueTurn()
    run = run_accuracy(_door_window_first("opening_centre"), RunSettings(trials=2, seed=7, calibration="oracle", time_scale=0.0),
                       progress=False, workdir=tmp_path / "w", hooks=hooks)  # fmt: skip
    trial = run.trials[1]
    assert trial.recipe == "door-window" and abs(hooks.rz_deg[1]) < 2.0  # an ordinary car body: inside +-2 deg
    assert trial.outcome == "done", f"refused an ordinary door-window car body: {trial.reason}"
    e = trial.true_error or {}
    assert max(abs(e["dx_mm"]), abs(e["dy_mm"]), abs(e["dz_mm"])) < 0.5, e
    assert max(abs(e["drx_deg"]), abs(e["dry_deg"]), abs(e["drz_deg"])) < 1.0, e
    # The record (sqlite3): shot 0 measured the turn more than a verification step (0.5 deg) short of the truth.
    db = sqlite3.connect(tmp_path / "w" / "var" / "bench.db")
    shots = {}
    for (fj,) in db.execute("select figures_json from cycle_steps where cycle_id = ? and step = ?",
                            (trial.cycle_id, int(CycleStep.COMPENSATE.value))):  # fmt: skip
        f = json.loads(fj or "{}")
        if "shot" in f:
            shots[f["shot"]] = f
    db.close()
    assert abs(shots[0]["offset_deg"] - hooks.rz_deg[1]) > 0.5, (shots[0], hooks.rz_deg[1])
    assert len(shots) >= 3  # shot 0 and at least two verification shots
