"""Which device backs each port, and how to reach it.

``kind = "sim"`` uses the twin's in-process device; the other kinds name a driver in ``drivers/``.
The composition root maps these sections to driver constructors; the core never imports a driver.
"""

from __future__ import annotations

from typing import Annotated, Literal, Union

from pydantic import Field

from cellctl.config.types import Finite, StrictModel


class SimLaserDevice(StrictModel):
    """The twin's laser, in-process."""

    kind: Literal["sim"] = "sim"


class SimCameraDevice(StrictModel):
    """The twin's camera, in-process."""

    kind: Literal["sim"] = "sim"


class SimRobotDevice(StrictModel):
    """The twin's robot, in-process."""

    kind: Literal["sim"] = "sim"


LaserDevice = Annotated[Union[SimLaserDevice], Field(discriminator="kind")]
CameraDevice = Annotated[Union[SimCameraDevice], Field(discriminator="kind")]
RobotDevice = Annotated[Union[SimRobotDevice], Field(discriminator="kind")]


class DevicesConfig(StrictModel):
    """The three devices of the cell."""

    laser: LaserDevice = SimLaserDevice()
    camera: CameraDevice = SimCameraDevice()
    robot: RobotDevice = SimRobotDevice()
    call_timeout_s: Finite = Field(5.0, gt=0, le=600)
