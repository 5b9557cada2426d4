"""The [devices.robot] kind = "abb" section and the driver's settings agree."""

from __future__ import annotations

import dataclasses

import pytest
from pydantic import ValidationError

from abb_robot import AbbRobotSettings
from cellctl.config.devices import AbbRobotDevice, DevicesConfig


def test_device_section_maps_one_to_one_onto_the_driver_settings() -> None:
    device_fields = set(AbbRobotDevice.model_fields) - {"kind"}
    settings_fields = {f.name for f in dataclasses.fields(AbbRobotSettings)}
    assert device_fields == settings_fields
    device = AbbRobotDevice(kind="abb", host="192.168.125.1")
    settings = AbbRobotSettings(**device.model_dump(exclude={"kind"}))
    defaults = AbbRobotSettings(host="192.168.125.1")
    assert settings == defaults  # same defaults on both sides


def test_robot_union_accepts_abb() -> None:
    cfg = DevicesConfig.model_validate({"robot": {"kind": "abb", "host": "10.0.0.5", "rapid_port": 30200,
                                                  "egm_port": None, "tool": "tGripper"}})
    assert isinstance(cfg.robot, AbbRobotDevice)
    assert cfg.robot.egm_port is None and cfg.robot.tool == "tGripper"


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"host": ""}, "host"),
        ({"host": "h", "rapid_port": 70000}, "rapid_port"),
        ({"host": "h", "tool": "my tool"}, "tool"),
        ({"host": "h", "heartbeat_period_s": 12.0}, "drops a client silent for 10 s"),
        ({"host": "h", "reconnect_delay_s": 5.0, "reconnect_max_delay_s": 1.0}, "reconnect_max_delay_s"),
        ({"host": "h", "egm_cond_time_s": 0.0}, "egm_cond_time_s"),
        ({"host": "h", "speed": 100}, "speed"),
    ],
)
def test_bad_sections_are_refused_with_the_field(fields: dict[str, object], message: str) -> None:
    with pytest.raises(ValidationError, match=message):
        AbbRobotDevice(kind="abb", **fields)  # type: ignore[arg-type]
