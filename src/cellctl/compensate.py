"""Install pose compensation, paper section 4.3.

Teaching (4.3 step 1) records, all as robot (belief) poses in the base frame B:
``T0`` the workpiece frame at the window's upper-right corner, ``C_Pos_0`` the flange pose at the
standard shooting pose, and ``g_Pos_0`` the flange pose with the glass correctly installed.
Production (4.3 step 2): after laser alignment the flange is at ``C_Pos_1``; the workpiece frame
moves with it, ``T1 = C_Pos_1 @ inv(inv(T0) @ C_Pos_0)``; vision's in-plane offset T' gives
``T2 = T1 @ T'``; the glass goes to ``g_Pos_0`` executed in T2: ``T2 @ inv(T0) @ g_Pos_0``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cellctl.geometry.planar import PlanarOffset
from cellctl.geometry.pose import Pose, check_pose, invert_pose, pose_error
from cellctl.geometry.rotation import matrix_to_xyz_fixed


class CorrectionLimitError(ValueError):
    """A correction would move the robot farther than the configured limits allow."""


@dataclass(frozen=True)
class TaughtPoses:
    """What teaching recorded (paper 4.3 step 1), as flange/frame poses in B."""

    T0: Pose
    C_Pos_0: Pose
    g_Pos_0: Pose

    def __post_init__(self) -> None:
        for name in ("T0", "C_Pos_0", "g_Pos_0"):
            check_pose(getattr(self, name), f"taught {name}")

    @property
    def T_T0_Cpos0(self) -> Pose:
        """The shooting flange pose in the workpiece frame: ``inv(T0) @ C_Pos_0``."""
        return invert_pose(self.T0) @ self.C_Pos_0

    @property
    def T_T0_gpos0(self) -> Pose:
        """The install flange pose in the workpiece frame: ``inv(T0) @ g_Pos_0``."""
        return invert_pose(self.T0) @ self.g_Pos_0


def workpiece_frame_after_alignment(taught: TaughtPoses, C_Pos_1: Pose) -> Pose:
    """T1 = C_Pos_1 @ inv(inv(T0) @ C_Pos_0): the workpiece frame as the aligned camera implies it."""
    return check_pose(C_Pos_1, "C_Pos_1") @ invert_pose(taught.T_T0_Cpos0)


def corrected_workpiece_frame(T1: Pose, offset: PlanarOffset) -> Pose:
    """T2 = T1 @ T': the workpiece frame corrected by vision's in-plane offset."""
    return T1 @ offset.as_pose()


def install_pose(taught: TaughtPoses, T2: Pose) -> Pose:
    """The install target: g_Pos_0 executed in the corrected workpiece frame, ``T2 @ inv(T0) @ g_Pos_0``."""
    return T2 @ taught.T_T0_gpos0


def shooting_pose_in(taught: TaughtPoses, T: Pose) -> Pose:
    """The standard shooting pose taken relative to workpiece frame ``T`` (for verification shots)."""
    return T @ taught.T_T0_Cpos0


@dataclass(frozen=True)
class CorrectionSize:
    """How far a corrected pose is from the taught one: translation (mm) and rotation (rad)."""

    translation_mm: float
    rotation_rad: float


def check_correction(
    taught_pose: Pose, corrected_pose: Pose, *, max_translation_mm: float, max_rotation_rad: float, what: str
) -> CorrectionSize:
    """Refuse a correction larger than the limits (a wrong measurement must not throw the robot)."""
    dt, dr = pose_error(taught_pose, corrected_pose)
    size = CorrectionSize(float(np.linalg.norm(dt)), float(np.linalg.norm(dr)))
    if not (size.translation_mm <= max_translation_mm and size.rotation_rad <= max_rotation_rad):  # NaN too
        raise CorrectionLimitError(
            f"{what} moves {size.translation_mm:.2f} mm and {np.degrees(size.rotation_rad):.3f} deg from "
            f"the taught pose; the limits are {max_translation_mm:g} mm and "
            f"{np.degrees(max_rotation_rad):g} deg (check the car body's position or the measurement)"
        )
    return size


def deviation_in_frame(T_ref: Pose, T: Pose) -> tuple[np.ndarray, np.ndarray]:
    """The paper's six figures of ``T`` relative to ``T_ref``, in ``T_ref``'s axes.

    Returns (dX, dY, dZ) in mm and (dRx, dRy, dRz) in rad as XYZ fixed angles (gamma, beta, alpha).
    """
    E = invert_pose(T_ref) @ T
    alpha, beta, gamma = matrix_to_xyz_fixed(E[:3, :3])
    return E[:3, 3].copy(), np.array([gamma, beta, alpha])
