"""A whole simulated cell in-process: the twin and its three devices behind the ports.

The rig is what the simulated cell's composition uses when the devices are the twin's own
(``kind = "sim"``); the protocol fakes of the driver packages take their physics from the same
:class:`SimCell`.
"""

from __future__ import annotations

from collections.abc import Mapping

from cellctl.config.sim import SimConfig
from cellctl.sim.camera import CameraRenderer
from cellctl.sim.camera_device import SimCamera
from cellctl.sim.cell import SimCell
from cellctl.sim.devices import SimDisplacementSensor, SimRobot
from cellctl.sim.streams import rng_stream
from cellctl.sim.targets import PlacedTarget

CAMERA_NOISE = "camera.noise"
TEACH_CAMERA_NOISE = "camera.noise.teach"


class SimRig:
    """The twin with its laser, camera and robot.

    Attributes:
        cell: the twin (truth, physics).
        renderer: the camera's image formation (its ray map is built once, here).
        targets: the calibration targets stuck on the wall now (the camera renders them).
        laser, camera, robot: the devices, implementing the ports.
    """

    def __init__(self, config: SimConfig, *, seed: int | None = None) -> None:
        self.cell = SimCell(config, seed=seed)
        self.renderer = CameraRenderer(config.camera.intrinsics, config.camera.render)
        self.targets: list[PlacedTarget] = []
        self.laser = SimDisplacementSensor(self.cell)
        self.robot = SimRobot(self.cell)
        self.camera = SimCamera(
            self.renderer, self.cell.true_camera_pose, self.cell.world, rng_stream(self.cell.seed, CAMERA_NOISE),
            targets=lambda: tuple(self.targets),
        )
        self.teach_rng = rng_stream(self.cell.seed, TEACH_CAMERA_NOISE)

    # SimTruth of the orchestrator

    def new_car_body(self) -> None:
        """The next car body arrives at a random posture."""
        self.cell.new_car_body()

    def install_error(self) -> Mapping[str, float]:
        """The paper's six figures of the glass where the flange really stands now."""
        return self.cell.install_error().as_dict()

    async def close(self) -> None:
        for dev in (self.laser, self.camera, self.robot):
            await dev.close()
