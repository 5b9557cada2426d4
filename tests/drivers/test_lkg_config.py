"""The [devices.laser] / [devices.camera] sections for real hardware, and building the drivers from them."""

from __future__ import annotations

import tomllib
from typing import Any

import pytest
from pydantic import ValidationError

from cellctl.config.devices import DevicesConfig, GenicamCameraDevice, KeyenceLkgDevice
from genicam_camera import GenicamCamera
from keyence_lkg import FakeLkgController, KeyenceLkgSensor, ReconnectPolicy

HARDWARE_EXAMPLE = """
[laser]
kind = "keyence_lkg"
port = "/dev/serial/by-id/usb-FTDI_FT232R_USB_UART_A10KLKG0-if00-port0"
baud = 115200
dialect = "LK-G5001"
output = 1
display_unit = "0.001mm"
reference_distance_mm = 350.0
displacement_positive = "away_from_head"
exchange_timeout_s = 0.5
mode_change_timeout_s = 3.0

[laser.reconnect]
attempts = 5
interval_s = 0.5

[camera]
kind = "genicam"
cti_path = "/opt/mvIMPACT_Acquire/lib/x86_64/mvGenTLProducer.cti"
serial_number = "FF008343"
pixel_format = "Mono8"
exposure_us = 8000.0
gain_db = 0.0
trigger_mode = "software"
timeout_s = 5.0
"""


def test_the_hardware_example_validates() -> None:
    devices = DevicesConfig.model_validate(tomllib.loads(HARDWARE_EXAMPLE))
    assert isinstance(devices.laser, KeyenceLkgDevice) and devices.laser.dialect == "LK-G5001"
    assert isinstance(devices.camera, GenicamCameraDevice) and devices.camera.exposure_us == 8000.0


def laser_section(**overrides: Any) -> dict[str, Any]:
    section: dict[str, Any] = tomllib.loads(HARDWARE_EXAMPLE)["laser"]
    section.update(overrides)
    return {k: v for k, v in section.items() if v is not None}


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"dialect": None}, "dialect"),  # required, never guessed
        ({"dialect": "LK-G5000"}, "dialect"),
        ({"display_unit": None}, "display_unit"),
        ({"display_unit": "um"}, "display_unit"),
        ({"reference_distance_mm": None}, "reference_distance_mm"),
        ({"displacement_positive": None}, "displacement_positive"),
        ({"baud": 14400}, "baud"),
        ({"dialect": "LK-G3001", "output": 3}, "LK-G3001 has OUT1 and OUT2 only"),
        ({"exchange_timeout_s": 0}, "exchange_timeout_s"),
        ({"port": ""}, "port"),
        ({"parity": "E"}, "parity"),  # unknown fields are refused
    ],
)
def test_bad_laser_sections_are_refused(overrides: dict[str, Any], message: str) -> None:
    with pytest.raises(ValidationError, match=message):
        DevicesConfig.model_validate({"laser": laser_section(**overrides)})


async def test_the_driver_is_built_from_the_section() -> None:
    with FakeLkgController("LK-G3001", lambda: 352.5) as fake:
        section = laser_section(port=fake.path, dialect="LK-G3001")
        config = DevicesConfig.model_validate({"laser": section}).laser
        sensor = KeyenceLkgSensor.from_config(config.model_dump())
        assert sensor.reconnect == ReconnectPolicy(attempts=5, interval_s=0.5)
        assert sensor.dialect == "LK-G3001" and sensor.port == fake.path
        reading = await sensor.read(timeout_s=1.0)
        assert reading.distance_mm == pytest.approx(352.5)
        await sensor.close()


def test_the_camera_adapter_is_built_from_the_section() -> None:
    config = DevicesConfig.model_validate(tomllib.loads(HARDWARE_EXAMPLE)).camera
    camera = GenicamCamera.from_config(config.model_dump())
    assert (camera.serial_number, camera.exposure_us, camera.trigger_mode) == ("FF008343", 8000.0, "software")


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"cti_path": ""}, "cti_path"),
        ({"trigger_mode": "hardware"}, "trigger_mode"),
        ({"pixel_format": "RGB8"}, "pixel_format"),
        ({"exposure_us": -1.0}, "exposure_us"),
        ({"exposure": 100.0}, "exposure"),
    ],
)
def test_bad_camera_sections_are_refused(overrides: dict[str, Any], message: str) -> None:
    section: dict[str, Any] = tomllib.loads(HARDWARE_EXAMPLE)["camera"]
    section.update(overrides)
    with pytest.raises(ValidationError, match=message):
        DevicesConfig.model_validate({"camera": section})
