"""The budget by calibration part: each part swapped for the twin's truth, its effect on a cell's mean error."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cellctl.bench.budget import run_part_budget
from cellctl.bench.parts import PART_ROWS, perfect_nine_point, reteach
from cellctl.bench.report import format_part_budget
from cellctl.compensate import TaughtPoses
from cellctl.config import load_config
from cellctl.geometry.pose import make_pose, pose_error

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "config" / "sim.toml"


def _oracle(config: Any, seed: int) -> Any:
    from cellctl.sim.oracle import oracle_calibration
    from cellctl.sim.rig import SimRig

    return oracle_calibration(SimRig(config.sim, seed=seed), config)


def test_rows_read_each_part_against_what_it_was_swapped_from() -> None:
    rows = {r.key: r for r in PART_ROWS}
    assert rows["as-commissioned"].against is None
    assert rows["g_Pos_0"].against == "as-commissioned" and rows["nine_point"].against == "as-commissioned"
    # Measured through the camera, the hand-eye and the laser, teaching goes with each of them.
    for key in ("camera", "hand_eye", "laser"):
        assert rows[key].against == "re-taught" and "re-taught" in rows[key].chain
    assert rows["re-taught"].part == "teaching" and rows["re-taught"].against == "nine_point"
    assert {r.part for r in PART_ROWS if r.part} == {"camera", "hand_eye", "laser", "nine_point", "teaching", "g_Pos_0"}


@pytest.mark.timeout(120)
def test_true_parts_reproduce_the_oracle_teaching() -> None:
    from cellctl.sim.rig import SimRig

    config = load_config(CONFIG)
    oracle = _oracle(config, 3)
    rig = SimRig(config.sim, seed=3)
    # The perfect map for the true lens at the oracle's shooting pose is the oracle's map.
    m = perfect_nine_point(rig, config, oracle.lens, oracle.taught.C_Pos_0, oracle.taught.T0)
    assert np.allclose(m.matrix, oracle.nine_point.matrix, atol=1e-6)
    # Re-teaching with the true parts finds the oracle's shooting pose and template again (up to the noise).
    again = reteach(rig, config, oracle)
    assert np.allclose(again.taught.C_Pos_0[:3, 3], oracle.taught.C_Pos_0[:3, 3], atol=0.05)
    assert abs(again.template.u_px - oracle.template.u_px) < 0.1 and abs(again.template.v_px - oracle.template.v_px) < 0.1
    assert np.array_equal(again.taught.g_Pos_0, oracle.taught.g_Pos_0)
    # T0 follows from the re-taught shot as teaching computes it: near the true T0 the oracle holds.
    dt, dr = pose_error(oracle.taught.T0, again.taught.T0)
    assert np.linalg.norm(dt) < 0.3 and np.degrees(np.linalg.norm(dr)) < 0.01, (dt, np.degrees(dr))


@pytest.mark.timeout(300)
def test_a_wrong_g_Pos_0_is_named_and_its_bias_measured() -> None:
    config = load_config(CONFIG)
    shift_mm = 0.2

    def cell_calibration(cfg: Any, seed: int) -> Any:
        cal = _oracle(cfg, seed)
        T = cal.taught
        # g_Pos_0 taught 0.2 mm off along the workpiece's x axis: every install lands 0.2 mm off in X.
        wrong = T.T0 @ make_pose(np.eye(3), [shift_mm, 0.0, 0.0]) @ np.linalg.inv(T.T0) @ T.g_Pos_0
        return dataclasses.replace(cal, taught=TaughtPoses(T.T0, T.C_Pos_0, wrong))

    budget = run_part_budget(
        config, seeds=range(2, 3), trials=3, progress=False, keys=("as-commissioned", "g_Pos_0"),
        cell_calibration=cell_calibration,
    )  # fmt: skip
    (cell,) = budget.cells
    assert set(cell.rows) == {"as-commissioned", "g_Pos_0"}
    # The same postures in both rows.
    assert [p["T_B_T"] for p in cell.rows["as-commissioned"].probes] == [p["T_B_T"] for p in cell.rows["g_Pos_0"].probes]
    base, swapped = cell.mean("as-commissioned"), cell.mean("g_Pos_0")
    assert base["X"] == pytest.approx(np.mean([e["dx_mm"] for e in cell.rows["as-commissioned"].errors()]))
    effect = cell.effect("g_Pos_0")
    assert effect is not None and effect["X"] == pytest.approx(swapped["X"] - base["X"])
    assert effect["X"] == pytest.approx(-shift_mm, abs=0.03)
    assert abs(effect["Y"]) < 0.03 and abs(effect["Z"]) < 0.03
    assert budget.dominant()["X"] == "g_Pos_0"
    assert budget.rms_effects()["g_Pos_0"]["X"] == pytest.approx(abs(effect["X"]))
    text = format_part_budget(budget)
    assert "dominant calibration part per axis" in text and "X   teaching (g_Pos_0)" in text
    assert "cannot be swapped alone" in text
