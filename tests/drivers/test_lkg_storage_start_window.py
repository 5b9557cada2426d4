"""The LK-G storage's start window through the real driver and the protocol fake: the controller's own start
(the fake's record, time.monotonic) lies between the AS command's write and its echo noticed, however late
the host's event loop noticed the echo, and the window is as wide as that delay (the start stamp alone
carries it unsaid: a sweep paired with another sweep's latency would be that far off)."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from keyence_lkg import KeyenceLkgSensor, link
from keyence_lkg.fake import FakeLkgController

REF_MM = 350.0
BAUD = 115200
STALL_S = 0.02  # the event loop busy (a scrape, a dashboard page) when the AS echo comes back


@pytest.fixture(params=["LK-G3001", "LK-G5001"])
def fake(request: pytest.FixtureRequest) -> Iterator[FakeLkgController]:
    with FakeLkgController(request.param, lambda: REF_MM, display_unit="0.001mm") as controller:
        yield controller


def make_sensor(fake: FakeLkgController, ahead_s: float) -> KeyenceLkgSensor:
    return KeyenceLkgSensor(
        port=fake.path, baud=BAUD, dialect=fake.dialect, display_unit="0.001mm", reference_distance_mm=REF_MM,
        displacement_positive="away_from_head", exchange_timeout_s=1.0, mode_change_timeout_s=1.0,
        clock=lambda: time.monotonic() + ahead_s,
    )  # fmt: skip


def stall_after_as(monkeypatch: pytest.MonkeyPatch) -> list[float]:
    """Block the event loop ``STALL_S`` right after every AS is written: its echo is noticed that late.
    Returns the host-clock times the AS writes returned (the stalls' starts)."""
    original, written = link.SerialLine.write, []

    async def write(self: link.SerialLine, data: bytes, deadline: float) -> None:
        await original(self, data, deadline)
        if data.startswith(b"AS"):
            written.append(time.monotonic())
            time.sleep(STALL_S)

    monkeypatch.setattr(link.SerialLine, "write", write)
    return written


# A prompt host's window (a few ms) is scored on the host's clock: with the real-time tests, after the rest.
@pytest.mark.parametrize("stall", [pytest.param(False, marks=pytest.mark.realtime), True])
async def test_the_controllers_start_lies_in_the_window_and_a_late_notice_widens_it(
    fake: FakeLkgController, monkeypatch: pytest.MonkeyPatch, stall: bool
) -> None:
    ahead_s = 321.0  # the cell's clock runs ahead of the host's: the window is on the driver's clock
    written = stall_after_as(monkeypatch) if stall else []
    sensor = make_sensor(fake, ahead_s)
    try:
        assert sensor.storage_start_window() is None  # no storage started yet
        started = await sensor.start_storage(cycle_s=0.002, count=200, timeout_s=5.0)
        earliest, latest = sensor.storage_start_window()  # type: ignore[misc]
        await sensor.stop_storage(timeout_s=5.0)
    finally:
        await sensor.close()
    truth = fake.storage.started_at + ahead_s  # the controller's own start, on the driver's clock
    assert earliest <= truth <= latest, (earliest - truth, latest - truth)
    assert earliest <= started <= latest
    if stall:
        assert len(written) == 1
        # The echo is noticed at least STALL_S after the AS went out (the controller's start lies between,
        # wherever the fake's thread got to run), and the start stamp is that notice less the echo's 3
        # characters on the wire: the stall is in it, and the window says so.
        assert latest - (written[0] + ahead_s) >= STALL_S and latest - earliest >= STALL_S
        assert latest - started == pytest.approx(10.0 * len(b"AS\r") / BAUD, abs=1e-6)
    else:  # a prompt host: the window is the AS and its echo on the wire, a ms or so
        assert latest - earliest < 0.005 and abs(started - truth) < 0.005


async def test_an_echo_the_controller_sends_late_widens_the_window_too(fake: FakeLkgController) -> None:
    # The other side of the window: the controller starts at once but its echo comes 30 ms later
    # (a real device's reply time, or the fake's thread late); the start still lies within.
    sensor = make_sensor(fake, 0.0)
    try:
        await sensor.start_storage(cycle_s=0.002, count=200, timeout_s=5.0)  # setup written
        await sensor.stop_storage(timeout_s=5.0)
        fake.delay(0.0)  # AQ's reply at once,
        fake.delay(0.03)  # AS's 30 ms after the controller started
        started = await sensor.start_storage(cycle_s=0.002, count=200, timeout_s=5.0)
        earliest, latest = sensor.storage_start_window()  # type: ignore[misc]
        await sensor.stop_storage(timeout_s=5.0)
    finally:
        await sensor.close()
    truth = fake.storage.started_at
    assert earliest <= truth <= latest and latest - earliest >= 0.03
    assert started - truth >= 0.025  # the stamp alone: the echo's delay in it
