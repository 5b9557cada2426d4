"""`devices.robot.egm_bind_host` unset follows the robot's host: a loopback robot (a virtual controller on this PC)
gets its EGM port bound on 127.0.0.1 only, any other host keeps 0.0.0.0; the kernel's socket table is the judge."""

from __future__ import annotations

import re
import socket
from pathlib import Path

import pytest
from abb_robot import AbbRobotSettings
from abb_robot.egm_session import egm_peer_for
from shared_support import free_port, run_cli

from cellctl.config import load_config

HARDWARE = Path(__file__).resolve().parents[2] / "config" / "hardware.example.toml"


def _example(tmp_path: Path, host: str, extra: str = "") -> Path:
    text = HARDWARE.read_text(encoding="utf-8")
    text, n = re.subn(r'\nhost = "192\.168\.125\.1"\n', f'\nhost = "{host}"\n{extra}', text, count=1)
    assert n == 1
    cfg = tmp_path / "cell.toml"
    cfg.write_text(text, encoding="utf-8")
    return cfg


def _bound_udp_address(port: int) -> str:
    """The local address the kernel lists for a UDP socket on ``port`` (/proc/net/udp, IPv4)."""
    for row in Path("/proc/net/udp").read_text().splitlines()[1:]:
        addr, hexport = row.split()[1].split(":")
        if int(hexport, 16) == port:
            return socket.inet_ntoa(bytes.fromhex(addr)[::-1])
    raise AssertionError(f"no UDP socket on port {port}")


async def test_a_loopback_robot_gets_its_egm_port_bound_on_loopback_only(tmp_path: Path) -> None:
    port = free_port(socket.SOCK_DGRAM)
    config = load_config(_example(tmp_path, "127.0.0.1"))
    dev = config.devices.robot
    settings = AbbRobotSettings(**dev.model_dump(exclude={"kind"}) | {"egm_port": port, "egm_isolation": "thread"})
    peer = egm_peer_for(settings, "robot")  # as the hardware service makes it
    assert peer is not None
    await peer.start(timeout_s=10)
    try:
        assert _bound_udp_address(port) == "127.0.0.1"
    finally:
        await peer.close()


@pytest.mark.parametrize(("host", "extra", "bind"), [
    ("localhost", "", "127.0.0.1"), ("::1", "", "127.0.0.1"), ("192.168.125.1", "", "0.0.0.0"),
    ("127.0.0.1", 'egm_bind_host = "0.0.0.0"\n', "0.0.0.0"),  # set explicitly: kept
])  # fmt: skip
def test_the_default_follows_the_host_and_a_set_value_is_kept(
    host: str, extra: str, bind: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = _example(tmp_path, host, extra)
    assert load_config(cfg).devices.robot.egm_bind_host == bind
    rc, _, err = run_cli(capsys, "config", "check", "--config", str(cfg))
    assert rc == 0, err


def test_the_hardware_example_is_valid_and_binds_every_interface(capsys: pytest.CaptureFixture[str]) -> None:
    assert load_config(HARDWARE).devices.robot.egm_bind_host == "0.0.0.0"  # its robot is on the cell network
    rc, _, err = run_cli(capsys, "config", "check", "--config", str(HARDWARE))
    assert rc == 0, err
