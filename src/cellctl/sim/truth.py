"""What the twin knows and the controller does not, and how an install is scored against it.

The paper scores each trial by six figures: the displacement deviations in X, Y, Z (mm) and the
rotation deviations about X, Y, Z (deg) of the installed glass against the correct install, in
the workpiece frame (section 5.3, Figs. 5 and 6). The twin scores the same six figures, against
the truth rather than a manually guided reference install:

    E = inv(T_B_T) @ T_B_H @ T_H_G

is the true glass corner frame G expressed in the true workpiece frame T. Its translation is
(dX, dY, dZ) and its rotation, written as the paper's XYZ fixed angles (eq. 13:
R = Rz(dRz) @ Ry(dRy) @ Rx(dRx)), gives (dRx, dRy, dRz). A perfect install gives six zeros.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.domain import InstallDeviation
from cellctl.geometry.pose import Pose, check_pose, invert_pose
from cellctl.geometry.rotation import matrix_to_xyz_fixed
from cellctl.sim.world import World


class InstallError(InstallDeviation):
    """The twin's true six figures of one install, in the workpiece frame T."""

    @property
    def position_mm(self) -> NDArray[np.float64]:
        """(dX, dY, dZ) in mm."""
        return np.array([self.dx_mm, self.dy_mm, self.dz_mm])

    @property
    def rotation_deg(self) -> NDArray[np.float64]:
        """(dRx, dRy, dRz) in deg."""
        return np.array([self.drx_deg, self.dry_deg, self.drz_deg])

    def within(self, position_mm: float, orientation_deg: float) -> bool:
        """Whether every figure is within +-tolerance (paper: +-0.5 mm, +-1 deg), per axis as the paper reports."""
        return bool(
            np.all(np.abs(self.position_mm) <= position_mm) and np.all(np.abs(self.rotation_deg) <= orientation_deg)
        )

    def as_dict(self) -> dict[str, float]:
        """The six figures by name, for a cycle record."""
        return asdict(self)


def score_glass(T_B_G_true: ArrayLike, T_B_T_true: ArrayLike) -> InstallError:
    """The six figures of a glass whose corner frame truly stands at ``T_B_G_true`` (E = inv(T_B_T) @ T_B_G)."""
    G = check_pose(T_B_G_true, "true glass pose T_B_G")
    T = check_pose(T_B_T_true, "true workpiece frame T_B_T")
    E = invert_pose(T) @ G
    alpha, beta, gamma = matrix_to_xyz_fixed(E[:3, :3])
    return InstallError(
        dx_mm=float(E[0, 3]),
        dy_mm=float(E[1, 3]),
        dz_mm=float(E[2, 3]),
        drx_deg=float(np.degrees(gamma)),
        dry_deg=float(np.degrees(beta)),
        drz_deg=float(np.degrees(alpha)),
    )


def score_install(T_B_H_true: ArrayLike, T_B_T_true: ArrayLike, T_H_G: ArrayLike) -> InstallError:
    """The six figures of an install whose flange really stands at ``T_B_H_true``.

    Args:
        T_B_H_true: the true flange pose the robot reached (not what the controller reports).
        T_B_T_true: the true workpiece frame at the opening's upper-right corner.
        T_H_G: the glass corner frame in the flange frame.
    """
    H = check_pose(T_B_H_true, "true flange pose")
    G = check_pose(T_H_G, "glass frame T_H_G")
    return score_glass(H @ G, T_B_T_true)


@dataclass(frozen=True)
class CellTruth:
    """The true geometry of the cell at one car-body placement.

    Attributes:
        world: the car body as it stands (true wall and workpiece frame T).
        T_H_C: the camera's true mounting on the flange (hand-eye).
        laser_r, laser_l: the laser's true origin and unit direction in the flange frame.
        T_H_G: the glass's true corner frame in the flange frame.
    """

    world: World
    T_H_C: Pose
    laser_r: NDArray[np.float64]
    laser_l: NDArray[np.float64]
    T_H_G: Pose

    @property
    def T_B_T(self) -> Pose:
        """The true workpiece frame in the robot base frame."""
        return self.world.T_B_T.copy()

    def install_flange_pose(self) -> Pose:
        """The true flange pose that puts the glass corner frame G exactly onto T."""
        return self.world.T_B_T @ invert_pose(self.T_H_G)

    def camera_pose(self, T_B_H_true: ArrayLike) -> Pose:
        """The true camera pose T_B_C for a true flange pose."""
        return check_pose(T_B_H_true, "true flange pose") @ self.T_H_C

    def score_glass(self, T_B_G_true: ArrayLike) -> InstallError:
        """The six figures of a released glass truly standing at ``T_B_G_true``."""
        return score_glass(T_B_G_true, self.world.T_B_T)

    def score(self, T_B_H_true: ArrayLike) -> InstallError:
        """The six figures of an install with the flange truly at ``T_B_H_true``."""
        return score_install(T_B_H_true, self.world.T_B_T, self.T_H_G)
