"""What a cycle works with and gives back: its devices, its calibration, where it reports, its result.

:mod:`cellctl.cell.cycle` runs the cycle on these.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from cellctl.align import AlignmentResult
from cellctl.compensate import TaughtPoses
from cellctl.domain import CycleStep
from cellctl.geometry.planar import PlanarOffset
from cellctl.geometry.pose import Pose
from cellctl.inspection import MeasuredDeviation
from cellctl.ports import Camera, CartesianPose, DisplacementSensor, Robot
from cellctl.vision import AffineMap, CornerFeatures, Lens
from cellctl.vision.taught_profile import TaughtProfile


@dataclass(frozen=True)
class CellDevices:
    """The three devices a cycle uses, behind their ports, and the cell's clock.

    ``clock`` (s) times the cycle and its steps: the host's monotonic clock on a real cell; in
    simulation the twin's time line, on which a move takes the seconds a real robot would.
    """

    laser: DisplacementSensor
    camera: Camera
    robot: Robot
    clock: Callable[[], float] = time.monotonic


@dataclass(frozen=True)
class CycleCalibration:
    """What a cycle needs from the calibration set (all checked before production)."""

    lens: Lens
    T_H_C: Pose
    laser_r: np.ndarray
    laser_l: np.ndarray
    laser_range_mm: tuple[float, float]
    nine_point: AffineMap
    taught: TaughtPoses
    template: CornerFeatures
    taught_profile: TaughtProfile | None = None  # the template's edge profiles (None: not recorded; the rule alone counts)


class CycleRecorder(Protocol):
    """Where a running cycle reports what it does (the store, the event stream)."""

    async def step_started(self, step: CycleStep) -> None:
        """The cycle entered ``step``."""
        ...

    async def step_figures(self, step: CycleStep, figures: dict[str, Any]) -> None:
        """Figures of a step (JSON-serialisable), possibly several times per step."""
        ...

    async def image(self, name: str, png: bytes) -> None:
        """An annotated image of the cycle."""
        ...

    async def install_started(self, target: CartesianPose) -> None:
        """The install step begins: persist it and return only once it is durable.

        Called before the robot moves the glass towards the car body (the approach included), so a
        cycle that crashes from here on is never resumed and the install never repeated.
        """
        ...


@dataclass(frozen=True)
class ShotRecord:
    """One shot of the compensate loop and the offset it measured."""

    index: int
    offset: PlanarOffset
    corner_sigma_px: float


@dataclass(frozen=True)
class CycleResult:
    """What a finished cycle did.

    Attributes:
        workpiece_correction_mm / _rad: the corrected workpiece frame T2 relative to the taught T0,
            in T0's axes (dX, dY, dZ; dRx, dRy, dRz as XYZ fixed angles).
        install_target: the commanded install flange pose (belief, in B).
        install_reached: the flange pose read back after the move.
        alignment: the laser alignment's result.
        shots: the compensate loop's shots, first to last.
        measured: the inspection's six figures of the installed glass (None: inspection off).
        install_offset: the closed loop's offset the install target took out (None: none applied).
    """

    workpiece_correction_mm: np.ndarray
    workpiece_correction_rad: np.ndarray
    install_target: Pose
    install_reached: Pose
    alignment: AlignmentResult
    shots: tuple[ShotRecord, ...] = field(default=())
    measured: MeasuredDeviation | None = None
    install_offset: Pose | None = None
