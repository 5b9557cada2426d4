"""ABB robtarget <-> pose.

A robtarget is ``[[x, y, z], [q1, q2, q3, q4], [cf1, cf4, cf6, cfx], [eax_a .. eax_f]]`` with the
position in mm and the orientation as a unit quaternion in the order w, x, y, z. The robot
configuration and external axes are carried along unchanged; they do not enter the pose.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from cellctl.geometry.pose import Pose, check_pose, make_pose
from cellctl.geometry.rotation import matrix_to_quat, quat_to_matrix

# RAPID uses 9E9 for an external axis that is not in use.
EXTAX_UNUSED = 9e9


@dataclass(frozen=True)
class RobTarget:
    """An ABB robtarget: position (mm), quaternion (w, x, y, z), confdata and external axes."""

    trans: tuple[float, float, float]
    rot: tuple[float, float, float, float]
    robconf: tuple[int, int, int, int] = (0, 0, 0, 0)
    extax: tuple[float, ...] = field(default=(EXTAX_UNUSED,) * 6)

    def __post_init__(self) -> None:
        if len(self.trans) != 3 or not all(np.isfinite(self.trans)):
            raise ValueError(f"robtarget trans must be 3 finite numbers in mm, got {self.trans!r}")
        if len(self.rot) != 4 or not all(np.isfinite(self.rot)):
            raise ValueError(f"robtarget rot must be 4 finite numbers (q1..q4 = w, x, y, z), got {self.rot!r}")
        norm = float(np.linalg.norm(self.rot))
        if abs(norm - 1.0) > 1e-4:
            raise ValueError(
                f"robtarget rot has length {norm:.6f}; RAPID needs a unit quaternion (normalise it)"
            )
        if len(self.robconf) != 4:
            raise ValueError(f"robtarget robconf must be [cf1, cf4, cf6, cfx], got {self.robconf!r}")
        if len(self.extax) != 6:
            raise ValueError(f"robtarget extax must have 6 values (eax_a..eax_f), got {self.extax!r}")

    def to_rapid(self, decimals_mm: int = 3, decimals_q: int = 7) -> str:
        """The RAPID literal, e.g. ``[[x,y,z],[q1,q2,q3,q4],[cf1,cf4,cf6,cfx],[9E+09,...]]``."""

        def num(v: float, d: int) -> str:
            return "9E+09" if v >= EXTAX_UNUSED else f"{v:.{d}f}"

        t = ",".join(num(v, decimals_mm) for v in self.trans)
        q = ",".join(num(v, decimals_q) for v in self.rot)
        c = ",".join(str(int(v)) for v in self.robconf)
        e = ",".join(num(v, decimals_mm) for v in self.extax)
        return f"[[{t}],[{q}],[{c}],[{e}]]"


def robtarget_to_pose(rt: RobTarget) -> Pose:
    """The flange pose T_B_H (or tool pose in the work object) of a robtarget."""
    return make_pose(quat_to_matrix(rt.rot), rt.trans)


def pose_to_robtarget(
    T: ArrayLike,
    robconf: tuple[int, int, int, int] = (0, 0, 0, 0),
    extax: tuple[float, ...] = (EXTAX_UNUSED,) * 6,
) -> RobTarget:
    """A robtarget for pose ``T`` (w >= 0 quaternion), with the given confdata and external axes."""
    M = check_pose(T, "robtarget pose")
    q = matrix_to_quat(M[:3, :3])
    return RobTarget(
        trans=(float(M[0, 3]), float(M[1, 3]), float(M[2, 3])),
        rot=(float(q[0]), float(q[1]), float(q[2]), float(q[3])),
        robconf=robconf,
        extax=tuple(float(v) for v in extax),
    )
