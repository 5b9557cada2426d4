"""Which device backs each port, and how to reach it.

``kind = "sim"`` uses the twin's in-process device; the other kinds name a driver in ``drivers/``.
The composition root maps these sections to driver constructors; the core never imports a driver.
"""

from __future__ import annotations

import ipaddress
from typing import Annotated, Any, Literal, Union

from pydantic import Field, field_validator, model_validator

from cellctl.config.types import Finite, StrictModel


def is_loopback(host: object) -> bool:
    """Whether ``host`` (a name or an address) is this machine's loopback: localhost, 127.0.0.0/8 or ::1."""
    if not isinstance(host, str):
        return False
    name = host.strip().strip("[]").lower()
    if name == "localhost" or name.endswith(".localhost"):
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False


class SimLaserDevice(StrictModel):
    """The twin's laser, in-process."""

    kind: Literal["sim"] = "sim"


class SimCameraDevice(StrictModel):
    """The twin's camera, in-process."""

    kind: Literal["sim"] = "sim"


class SimRobotDevice(StrictModel):
    """The twin's robot, in-process."""

    kind: Literal["sim"] = "sim"


class SerialReconnect(StrictModel):
    """How a serial driver reopens its port after it vanished (USB adapter unplugged and back)."""

    attempts: int = Field(5, ge=1, le=1000)  # opens tried within one call before DeviceDisconnected
    interval_s: Finite = Field(0.5, gt=0, le=60)  # pause between two opens


class KeyenceLkgDevice(StrictModel):
    """A Keyence LK-G controller on RS-232C (drivers/keyence_lkg).

    The dialect and the display unit are read from here, never guessed: the two controllers
    speak different command sets and error codes, and the reply does not carry its unit. A
    reading's distance along the laser from r (eq. 1) is ``reference_distance_mm`` plus the
    displacement, signed by ``displacement_positive``; check both on the real head.
    """

    kind: Literal["keyence_lkg"]
    port: str = Field(min_length=1)  # e.g. /dev/serial/by-id/usb-FTDI_..., or the udev rule's /dev/lkg
    baud: Literal[9600, 19200, 38400, 57600, 115200] = 115200  # the controller's RS-232C setting; 8N1
    dialect: Literal["LK-G3001", "LK-G5001"]
    output: int = Field(1, ge=1, le=12)  # OUT number of the head (LK-G3001: 1 or 2)
    display_unit: Literal["0.01mm", "0.001mm", "0.0001mm", "0.00001mm", "0.1um", "0.01um"]
    reference_distance_mm: Finite = Field(gt=0, le=5000)  # distance from r at which the OUT reads 0
    displacement_positive: Literal["away_from_head", "toward_head"]
    exchange_timeout_s: Finite = Field(0.5, gt=0, le=10)  # one command and its reply
    mode_change_timeout_s: Finite = Field(3.0, gt=0, le=60)  # Q0/R0 (R0 takes 600 ms+ on an LK-G5001)
    reconnect: SerialReconnect = SerialReconnect()

    @model_validator(mode="after")
    def _output_exists(self) -> "KeyenceLkgDevice":
        if self.dialect == "LK-G3001" and self.output > 2:
            raise ValueError(
                f"output = {self.output}: the LK-G3001 has OUT1 and OUT2 only; set output to 1 or 2, "
                f"or dialect to 'LK-G5001' if the controller is an LK-G5001"
            )
        return self


class GenicamCameraDevice(StrictModel):
    """A GenICam camera through a GenTL producer (drivers/genicam_camera; needs the ``camera`` extra).

    Unset exposure and gain leave the camera's own values; a set one the camera cannot take is
    refused when the camera is opened.
    """

    kind: Literal["genicam"]
    cti_path: str = Field(min_length=1)  # the vendor's GenTL producer (.cti), left where it was installed
    serial_number: str | None = Field(None, min_length=1)  # picks the camera; None: the only camera found
    user_id: str | None = Field(None, min_length=1)  # DeviceUserID, an alternative to the serial number
    pixel_format: Literal["Mono8", "Mono10", "Mono12", "Mono16"] = "Mono8"  # deeper formats are scaled to 8 bits
    exposure_us: Finite | None = Field(None, gt=0, le=10_000_000)
    gain_db: Finite | None = Field(None, ge=-20, le=48)
    trigger_mode: Literal["software", "free_run"] = "software"  # software: one trigger per grab
    timeout_s: Finite = Field(5.0, gt=0, le=120)  # opening the camera and writing its settings
    frame_lost_after_s: Finite = Field(1.0, gt=0, le=60)  # beyond the exposure: a triggered frame not come by then is lost


class AbbRobotDevice(StrictModel):
    """An ABB robot behind cellctl's RAPID server module, with EGM for fine corrections
    (drivers/abb_robot). Field names match ``abb_robot.AbbRobotSettings`` one for one.

    Poses are the flange in the base frame only with tool = "tool0" and wobj = "wobj0"; other
    names must exist in the controller's motion task and change the frame of every pose.
    """

    kind: Literal["abb"]
    host: str = Field(min_length=1)  # the controller's LAN/WAN address (not the service port)
    rapid_port: int = Field(30100, ge=1, le=65535)  # CELLCTL_PORT in CellctlServer.mod
    egm_port: int | None = Field(6511, ge=0, le=65535)  # UDP port the PC binds (UDPUC remote port); 0: no EGM
    egm_bind_host: str = Field("0.0.0.0", min_length=1)  # unset: 127.0.0.1 for a loopback host (a virtual controller)
    connect_timeout_s: Finite = Field(3.0, gt=0, le=60)
    request_timeout_s: Finite = Field(2.0, gt=0, le=60)  # the answer to a request answered at once (handshake, settings, POS, a motion's ACK)
    heartbeat_period_s: Finite = Field(1.0, gt=0, le=60)  # PING after this much quiet (the module drops a client after 10 s)
    heartbeat_timeout_s: Finite = Field(2.0, gt=0, le=60)  # no PONG within this: the link is dropped and rebuilt
    reconnect_delay_s: Finite = Field(0.5, gt=0, le=60)
    reconnect_max_delay_s: Finite = Field(5.0, gt=0, le=600)
    keepalive_idle_s: int = Field(10, ge=1, le=7200)  # TCP keepalive
    keepalive_interval_s: int = Field(3, ge=1, le=600)
    keepalive_count: int = Field(3, ge=1, le=100)
    tool: str = Field("tool0", pattern=r"^[A-Za-z][A-Za-z0-9_]{0,31}$")  # tooldata name on the controller
    wobj: str = Field("wobj0", pattern=r"^[A-Za-z][A-Za-z0-9_]{0,31}$")  # wobjdata name on the controller
    speed_mm_s: Finite = Field(100.0, gt=0, le=7000)  # until a move asks for its own speed
    speed_deg_s: Finite = Field(30.0, gt=0, le=1000)
    zone_mm: Finite = Field(0.0, ge=0, le=2000)  # 0: fine point (the Robot port's moves end at fine points)
    egm_receive_timeout_s: Finite = Field(0.5, gt=0, le=60)
    egm_cond_time_s: Finite = Field(0.1, gt=0, le=60)  # EGMRunPose \CondTime
    egm_max_correction_mm: Finite = Field(20.0, gt=0, le=500)  # larger EGM corrections are refused
    egm_max_correction_deg: Finite = Field(2.0, gt=0, le=45)
    egm_max_rate_hz: Finite = Field(250.0, gt=0, le=1000)
    egm_settle_cycles: int = Field(5, ge=1, le=1000)
    egm_rt_priority: int | None = Field(None, ge=1, le=99)  # SCHED_FIFO for the EGM loop (needs CAP_SYS_NICE)
    egm_isolation: Literal["process", "thread"] = "process"  # process: the EGM loop shares no GIL with the cell

    @field_validator("egm_port")
    @classmethod
    def _zero_is_off(cls, v: int | None) -> int | None:
        return None if v == 0 else v  # TOML has no null: egm_port = 0 switches EGM off

    @model_validator(mode="before")
    @classmethod
    def _egm_bind_follows_host(cls, data: Any) -> Any:
        """A robot on this machine (RobotStudio's virtual controller) sends EGM over loopback: bind only there."""
        if isinstance(data, dict) and "egm_bind_host" not in data and is_loopback(data.get("host")):
            return {**data, "egm_bind_host": "127.0.0.1"}
        return data

    @model_validator(mode="after")
    def _heartbeat_fits(self) -> "AbbRobotDevice":
        if self.heartbeat_period_s >= 10.0:
            raise ValueError(
                f"heartbeat_period_s = {self.heartbeat_period_s:g}: the RAPID server drops a client silent for "
                "10 s (CELLCTL_IDLE_TIMEOUT); use a period under 10 s"
            )
        if self.reconnect_max_delay_s < self.reconnect_delay_s:
            raise ValueError("reconnect_max_delay_s must be >= reconnect_delay_s")
        return self


class SimKeyenceLkgDevice(StrictModel):
    """The real LK-G driver against its protocol fake over a pseudo-terminal; distances from the twin.

    The simulated cell's way of exercising the serial driver: the same code path as a real
    controller, down to the bytes on the line.
    """

    kind: Literal["sim_keyence_lkg"]
    dialect: Literal["LK-G3001", "LK-G5001"] = "LK-G5001"
    display_unit: Literal["0.01mm", "0.001mm", "0.0001mm", "0.00001mm", "0.1um", "0.01um"] = "0.001mm"
    exchange_timeout_s: Finite = Field(0.5, gt=0, le=10)


class SimAbbDevice(StrictModel):
    """The real ABB driver against the fake controller on loopback; the fake moves the twin's robot."""

    kind: Literal["sim_abb"]
    request_timeout_s: Finite = Field(2.0, gt=0, le=60)
    heartbeat_period_s: Finite = Field(1.0, gt=0, lt=10)
    # EGM between the driver and the fake on a free loopback UDP port (its loop in a thread: a simulation
    # needs no isolated process); false: the driver has no EGM, and the cycle moves by RAPID only.
    egm: bool = True


LaserDevice = Annotated[Union[SimLaserDevice, KeyenceLkgDevice, SimKeyenceLkgDevice], Field(discriminator="kind")]
CameraDevice = Annotated[Union[SimCameraDevice, GenicamCameraDevice], Field(discriminator="kind")]
RobotDevice = Annotated[Union[SimRobotDevice, AbbRobotDevice, SimAbbDevice], Field(discriminator="kind")]


class DevicesConfig(StrictModel):
    """The three devices of the cell."""

    laser: LaserDevice = SimLaserDevice()
    camera: CameraDevice = SimCameraDevice()
    robot: RobotDevice = SimRobotDevice()
    call_timeout_s: Finite = Field(5.0, gt=0, le=600)
