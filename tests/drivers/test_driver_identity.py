"""Each real driver says what it is (cellctl.ports.Identified): what a commissioning dataset records as its source."""

from __future__ import annotations


from shared_support import tlsimu_path

from _abb_testkit import LOOPBACK, settings_for, start_fake
from abb_robot import AbbRobot
from cellctl.ports import Identified
from keyence_lkg import KeyenceLkgSensor
from keyence_lkg.fake import FakeLkgController


def _all_strings(identity: dict[str, str]) -> bool:
    return all(isinstance(k, str) and isinstance(v, str) for k, v in identity.items())


async def test_abb_robot_identity_comes_from_hello() -> None:
    fake = start_fake(time_scale=0.05)
    robot = AbbRobot(settings_for(fake))
    try:
        assert isinstance(robot, Identified)
        before = robot.identity()
        assert before == {"host": LOOPBACK, "rapid_port": str(fake.rapid_port), "robot_type": "", "rw_version": ""}
        await robot.connect(timeout_s=3.0)
        after = robot.identity()
        ident = fake.config.identity  # what the fake's HELLO reports (underscores on the wire, spaces here)
        assert after == {"host": LOOPBACK, "rapid_port": str(fake.rapid_port), "robot_type": ident.robot_type,
                         "rw_version": ident.rw_version}  # fmt: skip
        assert after["robot_type"].startswith("IRB 7600") and _all_strings(after)
    finally:
        await robot.close()
        fake.stop_thread()


async def test_keyence_identity_names_dialect_port_output_and_unit() -> None:
    with FakeLkgController("LK-G3001", lambda: 350.0, display_unit="0.01mm") as fake:
        laser = KeyenceLkgSensor(port=fake.path, dialect="LK-G3001", display_unit="0.01mm", reference_distance_mm=350.0,
                                 displacement_positive="away_from_head", output=2)  # fmt: skip
        try:
            assert isinstance(laser, Identified)
            assert laser.identity() == {"dialect": "LK-G3001", "port": fake.path, "output": "2", "display_unit": "0.01mm"}
            await laser.connect(timeout_s=2.0)  # nothing the controller says changes it
            assert laser.identity()["port"] == fake.path
        finally:
            await laser.close()


async def test_genicam_identity_before_and_after_open() -> None:
    tlsimu = tlsimu_path()
    from genicam_camera import GenicamCamera

    before = GenicamCamera(cti_path="/nowhere/producer.cti").identity()
    assert before == {"vendor": "", "model": "", "serial_number": "", "user_id": "", "cti_path": "/nowhere/producer.cti"}
    camera = GenicamCamera(cti_path=tlsimu, serial_number="SN_InterfaceA_0", timeout_s=10.0)
    try:
        assert isinstance(camera, Identified)
        info = await camera.open()
        ident = camera.identity()
        assert ident == {"vendor": info.vendor, "model": "TLSimuMono", "serial_number": "SN_InterfaceA_0",
                         "user_id": info.user_id, "cti_path": tlsimu}  # fmt: skip
        assert ident["vendor"] and _all_strings(ident)
    finally:
        await camera.close()
