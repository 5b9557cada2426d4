"""One laser alignment in the simulated cell, scored against the truth.

This is the step the cycle runs before shooting, done here without device I/O: the robot is
pose noise on commanded poses, the laser a ray cast with the LK-G500's error sources.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cellctl.align import AlignmentResult, camera_distance_to_plane, compute_alignment, plan_spot_poses
from cellctl.config.schema import CellConfig
from cellctl.geometry.plane import PlaneFit
from cellctl.geometry.rotation import angle_between_vectors
from cellctl.sim.world import World, nominal_world, sample_world


@dataclass(frozen=True)
class SimulatedAlignment:
    """An alignment run and its truth."""

    result: AlignmentResult
    world: World
    camera_axis_error_rad: float  # camera z under the aligned pose vs the true normal
    distance_error_mm: float  # true optical-centre distance at the aligned pose minus the target


def shooting_orientation(config: CellConfig) -> np.ndarray:
    """Taught flange rotation at the shooting pose: camera axes along the nominal T axes."""
    R_B_T0 = config.sim.world.T_B_T_nominal()[:3, :3]
    R_H_C = config.sim.camera.hand_eye.T_H_C()[:3, :3]
    return R_B_T0 @ R_H_C.T


def simulate_alignment(config: CellConfig, rng: np.random.Generator) -> SimulatedAlignment:
    """Place the car body at a random posture, measure the spots, align, and score the result."""
    world = sample_world(config.sim.world, rng)
    laser = config.sim.laser
    T_H_C = config.sim.camera.hand_eye.T_H_C()
    R_meas = shooting_orientation(config)
    T_B_T0 = nominal_world(config.sim.world).T_B_T
    commanded = plan_spot_poses(
        T_B_T0, config.process.align.spots_mm, R_meas, laser.r, laser.l, config.process.align.laser_standoff_mm
    )
    sigma_robot = config.sim.robot.repeatability_mm
    linearity = laser.linearity_fraction_fs * laser.full_scale_mm
    distances = []
    for T_cmd in commanded:
        T_true = T_cmd.copy()
        T_true[:3, 3] += rng.normal(0.0, sigma_robot, 3)
        origin = T_true[:3, :3] @ laser.r + T_true[:3, 3]
        d, _ = world.ray_hit(origin, T_true[:3, :3] @ laser.l)
        if d is None:
            raise RuntimeError("a planned laser spot missed the wall; check process.align.spots_mm")
        distances.append(d + rng.uniform(-linearity, linearity) + rng.normal(0.0, laser.noise_mm))
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
    T_B_C = result.T_B_H_aligned @ T_H_C
    axis_err = angle_between_vectors(T_B_C[:3, 2], world.normal_B)
    true_plane = _true_plane(world)
    dist_err = camera_distance_to_plane(result.T_B_H_aligned, T_H_C, true_plane) - config.process.working_distance_mm
    return SimulatedAlignment(result, world, axis_err, dist_err)


def _true_plane(world: World) -> PlaneFit:
    n = world.normal_B
    E = np.column_stack([n, world.T_B_T[:3, 0], world.T_B_T[:3, 1]])
    return PlaneFit(n, world.offset_B, world.T_B_T[:3, 3], np.array([0.0, 1.0, 1.0]), E, np.zeros(3))

