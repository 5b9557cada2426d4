"""The LK-G driver rides through a silence of the serial line inside one read.

The real driver reads the protocol fake through a pseudo-terminal proxy that drops every byte both
ways for ``gap`` seconds from the read's start (a cable pulled and plugged back, a controller busy):
the commands sent meanwhile never reach the controller, and the driver's measurement and barriers
all go unanswered. With the cell's figures (read timeout 2 s, exchange timeout 0.5 s) a read whose
controller answers again with an exchange time left must return the value the fake sent last (its
truth), not wait for a reply to a barrier that was lost; a silence past the deadline is a DeviceTimeout.
"""

from __future__ import annotations

import asyncio
import itertools
import os
import pty
import select
import threading
import time
import tty
from collections.abc import Iterator
from pathlib import Path

import pytest

from cellctl.ports import DeviceTimeout, LaserStatus
from keyence_lkg import KeyenceLkgSensor, ReconnectPolicy
from keyence_lkg.fake import FakeLkgController

REF_MM = 350.0
READ_TIMEOUT_S = 2.0  # process.motion.read_timeout_s of the cell
EXCHANGE_TIMEOUT_S = 0.5  # devices.laser.exchange_timeout_s of the cell


class Ramp:
    """A distance that changes on every reply, so a stale reply would show as a wrong number."""

    def __init__(self) -> None:
        self._count = itertools.count()

    def __call__(self) -> float:
        return 320.0 + 0.0137 * (next(self._count) % 3000)


class SilentProxy:
    """A pseudo-terminal at ``link`` forwarding bytes to and from the fake's port; while ``silent``
    it drops them both ways."""

    def __init__(self, upstream: str, link: Path) -> None:
        self.silent = False
        self._up = os.open(upstream, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        tty.setraw(self._up)
        self._master, self._slave = pty.openpty()
        tty.setraw(self._slave)  # kept open: the master never sees EIO between the driver's opens
        os.set_blocking(self._master, False)
        os.symlink(os.ttyname(self._slave), link)
        self.path = str(link)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="lkg silent proxy", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        peer = {self._master: self._up, self._up: self._master}
        while not self._stop.is_set():
            ready, _, _ = select.select(list(peer), [], [], 0.05)
            for fd in ready:
                try:
                    data = os.read(fd, 4096)
                except BlockingIOError:
                    continue
                except OSError:
                    data = b""
                if data and not self.silent:
                    os.write(peer[fd], data)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        for fd in (self._master, self._slave, self._up):
            os.close(fd)


@pytest.fixture(params=["LK-G5001", "LK-G3001"])
def line(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[tuple[FakeLkgController, SilentProxy]]:
    with FakeLkgController(request.param, Ramp(), display_unit="0.001mm") as fake:
        proxy = SilentProxy(fake.path, tmp_path / "ttyLKG")
        try:
            yield fake, proxy
        finally:
            proxy.close()


def the_fakes_last_reading(fake: FakeLkgController, read_text: str) -> float:
    """The distance (mm) of the fake's last reply, which must answer the driver's read command."""
    last = fake.exchanges[-1]
    assert last.command == read_text, f"the fake's last exchange is {last}, not the read"
    assert last.reply is not None and last.values_mm and last.values_mm[0] is not None
    return REF_MM + last.values_mm[0]


async def read_through_a_gap(
    fake: FakeLkgController, proxy: SilentProxy, gap_s: float
) -> tuple[KeyenceLkgSensor, float, object]:
    """One read with the line silent for ``gap_s`` from its start: (sensor, seconds taken, reading or error)."""
    sensor = KeyenceLkgSensor(
        port=proxy.path,
        dialect=fake.dialect,
        display_unit="0.001mm",
        reference_distance_mm=REF_MM,
        displacement_positive="away_from_head",
        exchange_timeout_s=EXCHANGE_TIMEOUT_S,
        reconnect=ReconnectPolicy(attempts=3, interval_s=0.05),
    )
    await sensor.read(timeout_s=READ_TIMEOUT_S)  # the port open, the controller answering
    loop = asyncio.get_running_loop()
    proxy.silent = True
    back = loop.call_later(gap_s, setattr, proxy, "silent", False)
    start = time.monotonic()
    try:
        result: object = await asyncio.wait_for(sensor.read(timeout_s=READ_TIMEOUT_S), READ_TIMEOUT_S + 3.0)
    except DeviceTimeout as exc:
        result = exc
    finally:
        back.cancel()
    return sensor, time.monotonic() - start, result


@pytest.mark.parametrize("gap_s", [0.6, 1.2, 1.4])
async def test_a_read_whose_controller_answers_again_in_time_returns_the_true_value(
    line: tuple[FakeLkgController, SilentProxy], gap_s: float
) -> None:
    fake, proxy = line
    sensor, took_s, result = await read_through_a_gap(fake, proxy, gap_s)
    try:
        read_text = "MS,01" if fake.dialect == "LK-G5001" else "M1"
        assert not isinstance(result, Exception), f"silent {gap_s} s of a {READ_TIMEOUT_S} s read: {result}"
        assert result.status is LaserStatus.OK  # type: ignore[attr-defined]
        assert result.distance_mm == pytest.approx(the_fakes_last_reading(fake, read_text), abs=1e-9)  # type: ignore[attr-defined]
        # sent at the first exchange after the line is back, not at the call's deadline
        assert took_s < gap_s + 2 * EXCHANGE_TIMEOUT_S
        assert sensor.stats.resyncs >= 1
    finally:
        await sensor.close()


async def test_a_silence_past_the_deadline_is_a_timeout_and_the_next_read_is_true(
    line: tuple[FakeLkgController, SilentProxy],
) -> None:
    fake, proxy = line
    sensor, took_s, result = await read_through_a_gap(fake, proxy, READ_TIMEOUT_S + 0.5)
    try:
        assert isinstance(result, DeviceTimeout), result
        assert "no valid reply" in str(result) and took_s < READ_TIMEOUT_S + 0.3
        proxy.silent = False
        reading = await sensor.read(timeout_s=READ_TIMEOUT_S)
        read_text = "MS,01" if fake.dialect == "LK-G5001" else "M1"
        assert reading.distance_mm == pytest.approx(the_fakes_last_reading(fake, read_text), abs=1e-9)
    finally:
        await sensor.close()
