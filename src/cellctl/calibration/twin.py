"""The simulated cell as the calibration commands see it: the twin's devices and what an engineer does.

Commissioning happens with a car body at its nominal posture (the twin places it there). The
engineer's hands are simulated too: sticking a checkerboard on the car-body wall, taking it off,
and guiding the robot by hand to install the glass for teaching (the exact install plus a
hand-guiding error). Everything the calibration computes still comes through the ports: robot
poses as the controller reports them, distances from the sensor, frames from the camera.
"""

from __future__ import annotations

import numpy as np

from cellctl.calibration.board import BoardSpec
from cellctl.config.calibration_procedure import BoardConfig
from cellctl.config.schema import CellConfig
from cellctl.geometry.pose import Pose, make_pose
from cellctl.geometry.rotation import axis_angle_to_matrix
from cellctl.sim.camera import CameraRenderer
from cellctl.sim.camera_device import SimCamera
from cellctl.sim.cell import SimCell
from cellctl.sim.devices import SimDisplacementSensor, SimRobot
from cellctl.sim.streams import rng_stream
from cellctl.sim.targets import Checkerboard, PlacedTarget, place_on_world_plane
from cellctl.sim.world import nominal_world

CAMERA_NOISE = "camera.noise.calibration"  # its own draws, not the production camera's
OPERATOR = "calibration.operator"


class TwinCell:
    """The twin, its robot, laser and camera behind the ports, and the targets in view.

    Args:
        config: the cell configuration (its ``sim`` section builds the twin).
        seed: overrides the configured seed.
    """

    def __init__(self, config: CellConfig, *, seed: int | None = None) -> None:
        self.config = config
        self.cell = SimCell(config.sim, seed=seed)
        self.cell.place_car_body(nominal_world(config.sim.world))
        self.renderer = CameraRenderer(config.sim.camera.intrinsics, config.sim.camera.render)
        self.targets: list[PlacedTarget] = []
        self.robot = SimRobot(self.cell)
        self.laser = SimDisplacementSensor(self.cell)
        self.camera = SimCamera(
            self.renderer,
            self.cell.true_camera_pose,
            self.cell.world,
            rng_stream(self.cell.seed, CAMERA_NOISE),
            targets=lambda: tuple(self.targets),
        )
        self._operator_rng = rng_stream(self.cell.seed, OPERATOR)

    @property
    def seed(self) -> int:
        return self.cell.seed

    def describe(self) -> dict[str, object]:
        """Where the data came from, for the dataset manifest."""
        return {"cell": "simulated", "seed": self.cell.seed, "car_body": "nominal posture"}

    def stick_board(self, board: BoardConfig, at_mm: tuple[float, float]) -> PlacedTarget:
        """Stick a checkerboard flat on the car-body wall, first inner corner at ``at_mm`` in T."""
        target = Checkerboard(inner_corners=board.inner_corners, square_mm=board.square_mm, border_mm=board.border_mm)
        placed = PlacedTarget(target, place_on_world_plane(self.cell.world().T_B_T, at_mm))
        self.targets = [placed]
        return placed

    def remove_targets(self) -> None:
        self.targets = []

    def operator_install_pose(self, position_sigma_mm: float, orientation_sigma_deg: float) -> Pose:
        """The flange pose an operator leaves the robot at after guiding the glass into the opening.

        The exact install (what a perfect controller would command, see SimCell.install_command)
        moved by the hand-guiding error: a normal draw per axis, in the glass corner frame.
        """
        exact = self.cell.install_command()
        z = self._operator_rng.normal(size=6)
        err = make_pose(axis_angle_to_matrix(np.deg2rad(orientation_sigma_deg) * z[3:]), position_sigma_mm * z[:3])
        T_H_G = self.cell.T_H_G
        return exact @ T_H_G @ err @ np.linalg.inv(T_H_G)

    async def close(self) -> None:
        for dev in (self.robot, self.laser, self.camera):
            await dev.close()


def board_spec(board: BoardConfig) -> BoardSpec:
    return BoardSpec(tuple(board.inner_corners), float(board.square_mm))  # type: ignore[arg-type]
