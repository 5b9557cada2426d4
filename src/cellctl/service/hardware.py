"""The real cell's composition root: the drivers of ``[devices]`` behind the ports, nothing simulated.

Only this module (and the simulated cell's root, for the devices it does not simulate) imports
the driver packages. It never imports :mod:`cellctl.sim`: the import contract in
``pyproject.toml`` (checked by the test suite) keeps it so.
"""

from __future__ import annotations

from pathlib import Path

from cellctl.config.devices import AbbRobotDevice, GenicamCameraDevice, KeyenceLkgDevice
from cellctl.config.schema import CellConfig
from cellctl.ports import Camera, DisplacementSensor, Robot
from cellctl.service.compose import Closer, Service, ServiceError, assemble_service


def keyence_laser(dev: KeyenceLkgDevice) -> tuple[DisplacementSensor, Closer]:
    from keyence_lkg import KeyenceLkgSensor

    laser = KeyenceLkgSensor.from_config(dev.model_dump())
    return laser, laser.close


def genicam_camera(dev: GenicamCameraDevice, size_px: tuple[int, int]) -> tuple[Camera, Closer]:
    from genicam_camera import GenicamCamera

    camera = GenicamCamera.from_config(dev.model_dump(), expected_size_px=size_px)
    return camera, camera.close


def abb_robot(dev: AbbRobotDevice) -> tuple[Robot, Closer]:
    from abb_robot import AbbRobot, AbbRobotSettings

    robot = AbbRobot(AbbRobotSettings(**dev.model_dump(exclude={"kind"})))
    return robot, robot.close


async def build_hardware_service(config: CellConfig, *, workdir: Path | None = None) -> Service:
    """The cell with its real devices (``mode = "hardware"``)."""
    dev = config.devices
    if config.mode != "hardware":
        raise ServiceError('the hardware root builds mode = "hardware" only; a simulated cell has its own root')
    if not (isinstance(dev.laser, KeyenceLkgDevice) and isinstance(dev.camera, GenicamCameraDevice) and isinstance(dev.robot, AbbRobotDevice)):
        raise ServiceError("mode = \"hardware\" needs real devices (keyence_lkg, genicam, abb) in [devices]")
    laser, close_laser = keyence_laser(dev.laser)
    camera, close_camera = genicam_camera(dev.camera, (config.layout.camera.width_px, config.layout.camera.height_px))
    robot, close_robot = abb_robot(dev.robot)
    service = await assemble_service(config, laser=laser, camera=camera, robot=robot, workdir=workdir)
    service.closers.extend([close_laser, close_camera, close_robot])
    return service
