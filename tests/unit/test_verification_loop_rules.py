"""The verification loop of the compensate step (paper 4.2): shots until the latest one's offset is within both the
translation and the turn residual, at least ``min_shots`` of them; the workpiece frame is the mean of the verification
shots' estimates. Driven with scripted shot offsets (the detector stands aside) and a robot that reaches every target,
so the right answer is known: which shot ends the loop, and the mean of the estimates, computed here with numpy."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from service_test_support import sim_config
from test_method_rules import INSTALL_TAUGHT as TAUGHT

from cellctl.cell.cycle import CycleRun
from cellctl.cell.cycle_failure import CycleFailed
from cellctl.domain import AlarmCode
from cellctl.geometry.planar import PlanarOffset
from cellctl.ports import CartesianPose
from cellctl.vision.corner import CornerFeatures

CORNER = CornerFeatures(1224.0, 1024.0, 0.0, 0.0, 1.5707963)  # both edges seen: its offsets turn


class _Robot:
    def __init__(self) -> None:
        self.at = CartesianPose.from_matrix(TAUGHT.C_Pos_0)
        self.moves = 0

    async def move(self, request: Any, *, timeout_s: float) -> CartesianPose:
        self.moves += 1
        self.at = request.target
        return request.target

    async def read_pose(self, *, timeout_s: float) -> CartesianPose:
        return self.at


class _Recorder:
    async def step_started(self, step: Any) -> None: ...
    async def step_figures(self, step: Any, figures: Any) -> None: ...
    async def image(self, name: str, png: bytes) -> None: ...


def _run(offsets: list[tuple[float, float, float]], **verify: Any) -> tuple[CycleRun, list[np.ndarray]]:
    """A run whose shots measure ``offsets`` in turn (mm, mm, rad), and the estimate each shot gave."""
    cfg = sim_config(**{"process.verify": verify})
    cal = SimpleNamespace(taught=TAUGHT, template=CORNER)
    run = CycleRun(SimpleNamespace(robot=_Robot()), cal, cfg.process, cfg.vision, _Recorder())  # type: ignore[arg-type]
    shots = iter(offsets)
    estimates: list[np.ndarray] = []

    async def measure(index: int, *, first: bool = False) -> tuple[Any, PlanarOffset]:
        m = SimpleNamespace(features=CORNER, measurement=None, kind="corner", sigma_px=0.05, message="")
        return m, PlanarOffset(*next(shots))

    estimate = run._estimate  # noqa: SLF001

    async def kept(*args: Any) -> np.ndarray:
        T = await estimate(*args)
        estimates.append(T)
        return T

    run._measure = measure  # type: ignore[method-assign]  # noqa: SLF001
    run._estimate = kept  # type: ignore[method-assign]  # noqa: SLF001
    return run, estimates


async def test_the_loop_ends_only_once_the_turn_too_is_within_its_residual_and_averages_the_verification_shots() -> None:
    turn = np.radians(0.03)  # over residual_deg 0.01 while the translation is well within residual_mm 0.05
    run, estimates = _run([(1.0, -0.5, 0.002), (0.01, 0.0, turn), (0.02, 0.01, 0.0)],
                          min_shots=1, max_shots=4, residual_mm=0.05, residual_deg=0.01)  # fmt: skip
    T_est, shots = await run.shoot_and_compensate(TAUGHT.C_Pos_0)
    assert [s.index for s in shots] == [0, 1, 2]  # shot 1 turned too much: one more
    verification = np.stack(estimates[1:])
    np.testing.assert_allclose(T_est[:3, 3], verification[:, :3, 3].mean(axis=0), atol=1e-9)


async def test_still_turning_after_max_shots_fails_naming_the_turn() -> None:
    turn = np.radians(0.03)
    run, _ = _run([(1.0, -0.5, 0.002), (0.0, 0.0, turn), (0.0, 0.0, turn)],
                  min_shots=1, max_shots=2, residual_mm=0.05, residual_deg=0.01)  # fmt: skip
    with pytest.raises(CycleFailed) as failed:
        await run.shoot_and_compensate(TAUGHT.C_Pos_0)
    assert failed.value.code is AlarmCode.RESIDUAL_OVER_LIMIT and "0.0300 deg" in failed.value.reason
