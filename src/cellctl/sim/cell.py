"""The twin's physics and truth: one car body at its posture, one robot with its laser, the true mountings.

:class:`SimCell` holds the state every simulated device reads (where the car body stands, where
the flange really is) and is the physics behind them: the in-process devices and the camera
(assembled with it in :class:`cellctl.sim.rig.SimRig`) and the driver packages' protocol fakes,
which take :meth:`SimCell.laser_reading`, :meth:`SimCell.execute` and :meth:`SimCell.motion_time`
as callbacks. :meth:`SimCell.truth` and :meth:`SimCell.install_error` score an install.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from cellctl.config.sim import SimConfig
from cellctl.geometry.pose import Pose
from cellctl.ports import LaserStatus
from cellctl.sim.arm import RobotArm
from cellctl.sim.glass import InstalledGlass, glass_scene
from cellctl.sim.laser import LaserModel
from cellctl.sim.robot import RobotModel
from cellctl.sim.streams import WORLD_POSTURE, rng_stream
from cellctl.sim.timeline import TwinTimeline
from cellctl.sim.truth import CellTruth, InstallError
from cellctl.sim.world import World, sample_world


class SimCell:
    """The digital twin of the cell, deterministic for a seed.

    Args:
        config: the ``[sim]`` section of the configuration.
        seed: overrides ``config.seed`` (e.g. one cell per benchmark run).
        clock: monotonic real time in seconds (injectable for tests).

    The first car-body posture is drawn at construction; :meth:`new_car_body` draws the next one
    (one per cycle). The robot starts at rest at its home pose.
    """

    def __init__(
        self, config: SimConfig, *, seed: int | None = None, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.config = config
        self.seed = config.seed if seed is None else int(seed)
        self.time_scale = config.time_scale
        self.robot_model = RobotModel(config.robot, self.seed)
        self.laser_model = LaserModel(config.laser, self.seed)
        self.timeline = TwinTimeline(config.time_scale, clock)
        line = self.timeline
        scale = config.time_scale
        self.arm = RobotArm(self.robot_model, time_scale=scale, clock=clock, waited=line.waited, line=line.now)
        self.T_H_C: Pose = config.camera.hand_eye.T_H_C()
        self.world_config, self.glass_config = config.world, config.glass  # the recipe now in the cell
        self.T_H_G: Pose = config.glass.T_H_G()
        self._posture_rng = rng_stream(self.seed, WORLD_POSTURE)
        self._world = sample_world(config.world, self._posture_rng)
        self._glass_on_gripper = True
        self._installed_T_B_G: Pose | None = None
        self._installed_scene: InstalledGlass | None = None

    # -- the car body ---------------------------------------------------------------------------

    def world(self) -> World:
        """The car body as it stands now."""
        return self._world

    def new_car_body(self, recipe: SimConfig | None = None) -> World:
        """The next car body arrives at a new random posture (the next cycle).

        ``recipe``: the twin's settings of the recipe it is built for (its opening, ``world``, and the
        glass the gripper takes, ``glass``); None: the same type as the last.
        """
        if recipe is not None:
            self.build_for(recipe)
        self._world = sample_world(self.world_config, self._posture_rng)
        self._next_glass()
        return self._world

    def build_for(self, recipe: SimConfig) -> None:
        """The car bodies from now on are of the recipe whose twin settings are ``recipe`` (its ``world``
        opening, and the ``glass`` the gripper takes); the body standing now stays where it is."""
        self.world_config, self.glass_config = recipe.world, recipe.glass
        self.T_H_G = recipe.glass.T_H_G()

    def place_car_body(self, world: World) -> None:
        """Put the car body at a given placement (tests, teaching at a known posture)."""
        if not isinstance(world, World):
            raise TypeError(f"place_car_body needs a World, got {type(world).__name__}")
        self._world = world
        self._next_glass()

    # -- the glass ------------------------------------------------------------------------------

    def _next_glass(self) -> None:
        """With a new car body comes a new glass on the gripper; nothing is installed in it yet."""
        self._glass_on_gripper = True
        self._installed_T_B_G = None
        self._installed_scene = None

    @property
    def glass_on_gripper(self) -> bool:
        """Whether the gripper holds a glass (from a new car body until it releases it)."""
        return self._glass_on_gripper

    def set_gripper(self, hold: bool) -> None:
        """The gripper's vacuum on (``hold``) or off.

        Off while it holds a glass: the glass stays where it truly stands (it is now installed, its
        pose T_B_G fixed in the car body) and the robot can back off. On picks nothing up: the next
        glass comes with the next car body.
        """
        if not hold and self._glass_on_gripper:
            self._installed_T_B_G = self.arm.true_pose() @ self.T_H_G
            self._installed_scene = glass_scene(self.glass_config, self._world, self._installed_T_B_G)
            self._glass_on_gripper = False

    def installed_glass(self) -> Pose | None:
        """The true pose T_B_G of the glass released in the opening, or None (not released yet)."""
        return None if self._installed_T_B_G is None else self._installed_T_B_G.copy()

    def installed_glass_scene(self) -> InstalledGlass | None:
        """The released glass as the camera and the laser see it (cellctl.sim.glass), or None."""
        return self._installed_scene

    # -- truth ----------------------------------------------------------------------------------

    def truth(self) -> CellTruth:
        """The true geometry at the current placement."""
        return CellTruth(
            self._world, self.T_H_C.copy(), self.laser_model.r.copy(), self.laser_model.l.copy(), self.T_H_G.copy()
        )

    def true_flange_pose(self) -> Pose:
        """Where the flange really is now."""
        return self.arm.true_pose()

    def belief_flange_pose(self) -> Pose:
        """What the controller reports now."""
        return self.arm.belief_pose()

    def true_camera_pose(self) -> Pose:
        """The camera's true pose T_B_C now (for the camera renderer)."""
        return self.arm.true_pose() @ self.T_H_C

    def install_error(self) -> InstallError:
        """The paper's six figures of the glass: where it was released, else as the flange holds it now."""
        if self._installed_T_B_G is not None:
            return self.truth().score_glass(self._installed_T_B_G)
        return self.truth().score(self.arm.true_pose())

    def install_command(self) -> Pose:
        """The belief target that, without repeatability noise, puts the glass exactly onto T.

        This is what a perfect controller would command; it differs from the true install pose
        by the robot's absolute-accuracy error there.
        """
        return self.robot_model.command_for(self.truth().install_flange_pose())

    # -- physics entry points -------------------------------------------------------------------

    def laser_reading(self, T_B_H_true: ArrayLike | None = None) -> tuple[LaserStatus, float | None]:
        """One laser reading: at ``T_B_H_true`` if given, else where the flange really is now."""
        T = self.arm.true_pose() if T_B_H_true is None else np.asarray(T_B_H_true, dtype=float)
        return self.laser_model.reading(T, self._world, self.installed_glass_scene())

    def execute(self, X: ArrayLike) -> Pose:
        """Move to belief target X at once; returns the true flange pose (raises ReachError if unreachable)."""
        return self.arm.execute(X)

    def motion_time(
        self, X_from: ArrayLike, X_to: ArrayLike, speed_mm_s: float | None = None, speed_deg_s: float | None = None
    ) -> float:
        """Seconds a real robot needs for the move (trapezoidal profiles plus settling)."""
        return self.robot_model.motion_time(X_from, X_to, speed_mm_s, speed_deg_s)
