"""One laser alignment in the simulated cell, scored against the truth.

This is the step the cycle runs before shooting, done here without device I/O: the robot is the
twin's robot model (belief targets in, true flange poses out, with its absolute-accuracy and
repeatability errors), the laser the twin's LK-G500 (ray cast from the true flange pose, with its
linearity and noise). The controller side sees only belief poses and reported distances; the
score uses the truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cellctl.align import AlignmentError, AlignmentResult, camera_distance_to_plane, compute_alignment, plan_spot_poses
from cellctl.config.schema import CellConfig
from cellctl.geometry.plane import PlaneFit
from cellctl.geometry.pose import Pose
from cellctl.geometry.rotation import angle_between_vectors
from cellctl.ports import LaserStatus
from cellctl.sim.cell import SimCell
from cellctl.sim.world import World, nominal_world


@dataclass(frozen=True)
class SimulatedAlignment:
    """An alignment run and its truth."""

    result: AlignmentResult
    world: World
    camera_axis_error_rad: float  # true camera z at the executed aligned pose vs the true normal
    distance_error_mm: float  # true optical-centre distance at the executed aligned pose minus the target
    T_B_H_aligned_true: Pose  # where the flange really went when the aligned pose was commanded


def shooting_orientation(config: CellConfig) -> np.ndarray:
    """Taught flange rotation at the shooting pose: camera axes along the nominal T axes."""
    R_B_T0 = config.sim.world.T_B_T_nominal()[:3, :3]
    R_H_C = config.sim.camera.hand_eye.T_H_C()[:3, :3]
    return R_B_T0 @ R_H_C.T


def run_alignment(cell: SimCell, config: CellConfig) -> SimulatedAlignment:
    """Measure the spots on the car body as it stands in ``cell``, align, move there, and score.

    Raises AlignmentError if a planned spot gives no reading (it fell into the opening or out of
    range), and ReachError if a pose is out of the robot's reach.
    """
    world = cell.world()
    laser = config.sim.laser
    T_H_C = config.sim.camera.hand_eye.T_H_C()
    T_B_T0 = nominal_world(config.sim.world).T_B_T
    commanded = plan_spot_poses(
        T_B_T0,
        config.process.align.spots_mm,
        shooting_orientation(config),
        laser.r,
        laser.l,
        config.process.align.laser_standoff_mm,
    )
    distances = []
    for k, X in enumerate(commanded):
        cell.execute(X)
        status, d = cell.laser_reading()
        if status is not LaserStatus.OK or d is None:
            raise AlignmentError(
                f"laser spot {k} gave no distance ({status.value}); move process.align.spots_mm[{k}] onto the "
                "wall and within the sensor's range"
            )
        distances.append(d)
    result = compute_alignment(
        commanded,
        np.array(distances),
        laser.r,
        laser.l,
        T_H_C,
        config.process.working_distance_mm,
        range_mm=(laser.range_min_mm, laser.range_max_mm),
        inlier_threshold_mm=config.process.align.inlier_threshold_mm,
        max_rms_mm=config.process.align.max_rms_mm,
        min_collinearity=config.process.align.min_collinearity,
    )
    T_true = cell.execute(result.T_B_H_aligned)
    truth = cell.truth()
    axis_err = angle_between_vectors(truth.camera_pose(T_true)[:3, 2], world.normal_B)
    dist_err = camera_distance_to_plane(T_true, truth.T_H_C, _true_plane(world)) - config.process.working_distance_mm
    return SimulatedAlignment(result, world, axis_err, dist_err, T_true)


def simulate_alignment(config: CellConfig, rng: np.random.Generator) -> SimulatedAlignment:
    """One alignment in a fresh simulated cell seeded from ``rng``.

    Each call builds its own cell (its own robot accuracy field and sensor errors, a new car-body
    posture), so a series of calls samples cells as well as postures; use :func:`run_alignment`
    with one :class:`SimCell` to run many cycles of the same cell.
    """
    cell = SimCell(config.sim, seed=int(rng.integers(0, 2**63 - 1)))
    return run_alignment(cell, config)


def _true_plane(world: World) -> PlaneFit:
    n = world.normal_B
    E = np.column_stack([n, world.T_B_T[:3, 0], world.T_B_T[:3, 1]])
    return PlaneFit(n, world.offset_B, world.T_B_T[:3, 3], np.array([0.0, 1.0, 1.0]), E, np.zeros(3))
