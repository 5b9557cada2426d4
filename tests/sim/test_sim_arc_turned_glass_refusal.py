"""Door window (arc corner): a glass released truly turned 3 deg in the opening is refused by the inspection, and
the record says so, not "software fault" (drawing the refused arc's centre, ~1e9 px off
the image, overflowed OpenCV). Truth: the twin's released glass (true error drz = +3 deg); the record read back
with sqlite3.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
from shared_support import door_window_first, glass_moved_at_release

from cellctl.bench.accuracy import RunSettings, run_accuracy
from cellctl.config import CellConfig
from cellctl.geometry.pose import make_pose
from cellctl.geometry.rotation import rot_z

def _door_window_first() -> CellConfig:
    return door_window_first(lambda data: data["process"]["spc"].update(enabled=False))  # each install shows its own error


# At release the glass lands turned 3 deg about its corner frame's z (the twin's truth turns with it).
TURN = make_pose(rot_z(np.radians(3.0)), [0.0, 0.0, 0.0])


def test_a_glass_turned_3_deg_is_refused_by_the_arc_inspection_with_its_reason(tmp_path: Path) -> None:
    run = run_accuracy(_door_window_first(), RunSettings(trials=2, seed=1, calibration="oracle", time_scale=0.0),
                       progress=False, workdir=tmp_path / "w", hooks=glass_moved_at_release(TURN))  # fmt: skip
    for trial in run.trials:  # the second's refused arc has its centre ~1e9 px off the image
        assert trial.true_error is not None and abs(trial.true_error["drz_deg"] - 3.0) < 0.05, trial.true_error
        assert trial.outcome == "failed", trial
        assert (trial.reason or "").startswith("inspect: the gaps on the arc could not be measured"), trial.reason
    db = sqlite3.connect(tmp_path / "w" / "var" / "bench.db")
    rows = db.execute("select id, state, error from cycles order by id").fetchall()
    images = {r[0] for r in db.execute("select cycle_id from cycle_images where name = 'inspect'")}
    db.close()
    assert [(state, (error or "").split(":")[0]) for _, state, error in rows] == [("failed", "inspect")] * 2, rows
    assert images == {rows[0][0], rows[1][0]}  # each refusal drawn for whoever has to find out why
