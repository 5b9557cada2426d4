"""The twin's EGM port: the fake controller sends to it from the start, the driver's peer binds it only at the first
EGM use. Drawn from the kernel's ephemeral range, it could meanwhile go to another socket (another twin's fake
sending EGM), whose datagrams the peer would take for its controller's."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from cellctl.config.devices import SimAbbDevice
from cellctl.config.sim import SimConfig
from cellctl.service.sim_fakes import abb_on_fake
from cellctl.sim.cell import SimCell

pytestmark = pytest.mark.timeout(60)


def _ephemeral_low() -> int:
    """The lowest port the kernel hands out for bind(0) and sending sockets (its own setting)."""
    return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])


async def test_the_twins_egm_port_is_never_one_the_kernel_hands_out_meanwhile() -> None:
    low = _ephemeral_low()
    ports = set()
    for _ in range(5):
        fakes: dict[str, object] = {}
        driver, close, _jog = abb_on_fake(SimCell(SimConfig(time_scale=0.001)), SimAbbDevice(kind="sim_abb"), fakes)
        try:
            port = driver.settings.egm_port
            assert port is not None and port < low, (port, low)
            assert fakes["robot"].config.egm_sensor_port == port  # type: ignore[attr-defined]  # where the fake sends
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.bind(("127.0.0.1", port))  # free until the peer binds it
            ports.add(port)
        finally:
            await close()
    assert len(ports) > 1  # drawn, not one fixed port for every twin on the machine
