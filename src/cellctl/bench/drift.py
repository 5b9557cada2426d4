"""A drift injected into the twin mid-run: the camera mount turning on the flange.

From cycle ``at`` of a run (1-based, the cycle's own number in the run), the twin's TRUE hand-eye
transform ``SimCell.T_H_C`` turns by ``angle_deg`` about one of the camera's own axes (``x``: the
image's u direction, which tilts the optical axis up or down and shifts the image along v; the
default), all at once or spread linearly over ``over`` cycles (cycle ``at`` gets ``1/over`` of it,
cycle ``at + over - 1`` all of it). The change is made between cycles, by the bench, on the twin the
simulated composition root built (``service.extras["twin"]``); the cell's calibration set does not
know about it, as a real cell would not after a knock to its camera bracket.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from cellctl.geometry.pose import Pose, invert_pose, make_pose

CAMERA_AXES = {"x": 0, "y": 1, "z": 2}


def _axis_rotation(axis: str, angle_rad: float) -> np.ndarray:
    """Rotation by ``angle_rad`` about the camera's own ``axis`` (right-handed)."""
    j = CAMERA_AXES[axis]
    v = np.zeros(3)
    v[j] = 1.0
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + np.sin(angle_rad) * K + (1.0 - np.cos(angle_rad)) * (K @ K)


def mount_angle_deg(T_H_C_now: Pose, T_H_C_start: Pose) -> float:
    """How far (deg) the camera mount has turned from ``T_H_C_start``: the angle of the relative rotation."""
    R = (invert_pose(T_H_C_start) @ T_H_C_now)[:3, :3]
    s = 0.5 * np.linalg.norm([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    c = (np.trace(R) - 1.0) / 2.0
    return float(np.degrees(np.arctan2(s, c)))  # exact near zero, where arccos of the trace is not


@dataclass(frozen=True)
class DriftSpec:
    """The camera mount turning by ``angle_deg`` about the camera's ``axis`` from cycle ``at`` over ``over`` cycles."""

    angle_deg: float
    at: int
    over: int = 1
    axis: str = "x"

    def __post_init__(self) -> None:
        from cellctl.bench.sources import BenchSettingsError

        if not np.isfinite(self.angle_deg) or abs(self.angle_deg) > 5.0:
            raise BenchSettingsError(f"--drift-camera-deg must be a number within +-5 deg, got {self.angle_deg}")
        if self.at < 1:
            raise BenchSettingsError(f"--drift-at must be a cycle number (1 or more), got {self.at}")
        if self.over < 1:
            raise BenchSettingsError(f"--drift-over must be at least 1 cycle, got {self.over}")
        if self.axis not in CAMERA_AXES:
            raise BenchSettingsError(f"the drift's axis must be one of {', '.join(CAMERA_AXES)} (the camera's), got {self.axis!r}")

    def angle_at(self, k: int) -> float:
        """The mount's turn (deg) during cycle ``k`` (1-based)."""
        if k < self.at:
            return 0.0
        return self.angle_deg * min(1.0, (k - self.at + 1) / self.over)

    def mount(self, T_H_C_start: Pose, k: int) -> Pose:
        """The twin's true T_H_C during cycle ``k``: the start mount turned about the camera's own axis."""
        R = _axis_rotation(self.axis, float(np.radians(self.angle_at(k))))
        return T_H_C_start @ make_pose(R, np.zeros(3))

    def describe(self) -> str:
        spread = "at once" if self.over == 1 else f"spread linearly over {self.over} cycles"
        return (
            f"the twin's camera mount turns {self.angle_deg:g} deg about the camera's {self.axis} axis "
            f"from cycle {self.at}, {spread}"
        )

    def as_dict(self) -> dict[str, Any]:
        return {"angle_deg": self.angle_deg, "at": self.at, "over": self.over, "axis": f"camera {self.axis}"}


class DriftInjector:
    """Applies a :class:`DriftSpec` to one twin between cycles and reports what the twin's mount really was.

    Args:
        spec: the drift (None: no drift; the injector then only reports the mount).
        cell: the twin's physics (``SimCell``), whose ``T_H_C`` is the true camera mount.
    """

    def __init__(self, spec: DriftSpec | None, cell: Any) -> None:
        self.spec = spec
        self.cell = cell
        self.start: Pose = np.array(cell.T_H_C, dtype=float).copy()

    def before_cycle(self, k: int) -> float:
        """Set the twin's true mount for cycle ``k``; returns the turn (deg) now in the twin, read back from it."""
        if self.spec is not None:
            self.cell.T_H_C = self.spec.mount(self.start, k)
        return mount_angle_deg(self.cell.T_H_C, self.start)
