"""The LK-G's data storage (issue 19: reading the wall on the move) through the real driver and the
protocol fake over a pseudo-terminal: the setup on the wire as the reference notes give it, every
stored reading at its instant (the distance source is a known function of time), no-value
readings as None, the setup written once, and a cycle the controller cannot store refused."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from cellctl.ports import LaserStatus, StoringSensor
from keyence_lkg import KeyenceLkgSensor
from keyence_lkg.fake import FakeLkgController

REF_MM = 350.0
SPEED_MM_S = 10.0  # the distance source moves this fast, so an instant's error shows as a distance error


class MovingWall:
    """350 mm plus 10 mm/s since it was made (a saw tooth of 5 s, so it stays in range), no value in every fifth
    0.1 s window; it can say what it read at any instant (a TimedSource), so the fake stores each reading for
    its exact instant however busy the host."""

    def __init__(self) -> None:
        self.t0 = time.monotonic()

    def __call__(self) -> float | LaserStatus:
        return self.at(time.monotonic())

    def at(self, t: float) -> float | LaserStatus:
        since = (t - self.t0) % 5.0
        return LaserStatus.NO_VALUE if int(since * 10) % 5 == 4 else REF_MM + SPEED_MM_S * since


@pytest.fixture(params=["LK-G3001", "LK-G5001"])
def fake(request: pytest.FixtureRequest) -> Iterator[FakeLkgController]:
    wall = MovingWall()
    with FakeLkgController(request.param, wall, display_unit="0.001mm") as controller:
        controller.wall = wall  # type: ignore[attr-defined]
        yield controller


def make_sensor(fake: FakeLkgController, clock: Callable[[], float] = time.monotonic) -> KeyenceLkgSensor:
    return KeyenceLkgSensor(
        port=fake.path, dialect=fake.dialect, display_unit="0.001mm", reference_distance_mm=REF_MM,
        displacement_positive="away_from_head", exchange_timeout_s=1.0, mode_change_timeout_s=1.0, clock=clock,
    )  # fmt: skip


async def set_sampling_200us(sensor: KeyenceLkgSensor) -> None:
    async with sensor.communication_mode(timeout_s=3.0):
        await sensor.write_setting("CA", "3" if sensor.dialect == "LK-G3001" else "6", timeout_s=1.0)


def sent(fake: FakeLkgController) -> list[str]:
    return [e.command for e in fake.exchanges]


async def test_the_driver_is_a_storing_sensor_and_each_reading_stands_for_its_instant(fake: FakeLkgController) -> None:
    sensor = make_sensor(fake)
    try:
        assert isinstance(sensor, StoringSensor)
        await set_sampling_200us(sensor)
        before = time.monotonic()
        started = await sensor.start_storage(cycle_s=0.002, count=5000, timeout_s=5.0)
        after = time.monotonic()
        await asyncio.sleep(0.6)
        stored = await sensor.stop_storage(timeout_s=10.0)
    finally:
        await sensor.close()
    # On the wire, as the notes give it: 200 us sampling x 10 (code 3) = 2 ms, OUT1, 5000 readings.
    setup = [c for c in sent(fake) if c.startswith("SW,C") or c.startswith("SW,OK")]
    if fake.dialect == "LK-G3001":
        assert setup == ["SW,CA,3", "SW,CI,1,05000,3"]
    else:
        assert setup == ["SW,CA,6", "SW,CF,0005000,03", "SW,OK,01,1"]
    assert sent(fake)[-5:] == ["AQ", "AS", "AP", "AN", "AO," + ("1" if fake.dialect == "LK-G3001" else "01")]
    assert stored.cycle_s == pytest.approx(0.002, rel=1e-9)
    # The first reading's instant: the controller's start lies within the call, and so does the driver's figure.
    assert stored.started_s == started and before <= started <= after
    assert before <= fake.storage.started_at <= after
    n = len(stored.distances_mm)
    assert n == fake.storage.taken and n >= 250, n  # 0.6 s at 2 ms, and what the stop took
    # Every reading, in order and none lost, is the wall at its instant on the controller's clock (to the
    # display's 0.001 mm), and no value exactly where the wall had none.
    wall: MovingWall = fake.wall  # type: ignore[attr-defined]
    truth = [wall.at(fake.storage.started_at + k * stored.cycle_s) for k in range(n)]
    missing = [k for k, v in enumerate(truth) if v is LaserStatus.NO_VALUE]
    assert [k for k, v in enumerate(stored.distances_mm) if v is None] == missing and len(missing) > 20
    shown = np.array([v for v in stored.distances_mm if v is not None])
    expected = np.array([v for v in truth if v is not LaserStatus.NO_VALUE], dtype=float)
    assert np.abs(shown - expected).max() <= 0.0006


async def test_the_setup_is_written_once_and_a_sweep_costs_five_exchanges(fake: FakeLkgController) -> None:
    sensor = make_sensor(fake)
    try:
        await set_sampling_200us(sensor)
        for _ in range(2):
            await sensor.start_storage(cycle_s=0.004, count=200, timeout_s=5.0)
            await asyncio.sleep(0.05)
            await sensor.stop_storage(timeout_s=5.0)
        assert sent(fake)[-5:][:2] == ["AQ", "AS"] and sent(fake).count("Q0") == 2  # CA, then the storage setup once
        # Fewer readings than the setup holds: no new setup, and no more readings than asked for.
        await sensor.start_storage(cycle_s=0.004, count=50, timeout_s=5.0)
        await asyncio.sleep(0.5)
        stored = await sensor.stop_storage(timeout_s=5.0)
        assert len(stored.distances_mm) == 50 and sent(fake).count("Q0") == 2
        # More: the setup is written again, and the storage ends by itself at its count.
        await sensor.start_storage(cycle_s=0.004, count=300, timeout_s=5.0)
        await asyncio.sleep(1.6)
        stored = await sensor.stop_storage(timeout_s=5.0)
        assert len(stored.distances_mm) == 300 and sent(fake).count("Q0") == 3
        assert fake.storage.taken == 300
    finally:
        await sensor.close()


async def test_a_cycle_the_controller_cannot_store_is_refused_with_the_choices(fake: FakeLkgController) -> None:
    sensor = make_sensor(fake)
    try:
        await set_sampling_200us(sensor)
        with pytest.raises(ValueError, match=r"3 ms is not .* choose one of 0.2, 0.4, 1, 2, 4, 10"):
            await sensor.start_storage(cycle_s=0.003, count=100, timeout_s=5.0)
        assert "AS" not in sent(fake)
        assert fake.mode == "general"  # the setup session was closed (R0) on the way out
    finally:
        await sensor.close()


def test_the_fake_refuses_the_read_out_while_it_stores() -> None:
    with FakeLkgController("LK-G5001", lambda: 350.0) as fake:
        assert fake._handle("SW,OK,01,1")[0] == "ER,SW,51"  # settings only in communication mode
        assert fake._handle("AS")[0] == "ER,AS,51"  # no OUT chosen for storage yet
        fake.mode = "communication"
        assert fake._handle("SW,OK,01,1")[0] == "SW,OK"
        fake.mode = "general"
        assert fake._handle("AS")[0] == "AS"
        assert fake._handle("AO,01")[0] == "ER,AO,51"
        assert fake._handle("AQ")[0] == "ER,AQ,51"
        assert fake._handle("AP")[0] == "AP"
        status = fake._handle("AN")[0].split(",")
        assert status[:2] == ["AN", "0"] and int(status[2]) >= 1
        assert fake._handle("AO,01")[0].startswith("AO,+000.000")
        assert fake._handle("AO,02")[0].startswith("ER,AO,")  # OUT2 was not stored


@pytest.mark.realtime  # scores how closely the driver dates the fake's start on the host's clock
async def test_the_storage_start_is_given_on_the_cells_clock(fake: FakeLkgController) -> None:
    # The cell pairs the stored readings with the robot's feedback on its own clock (the simulated cell's
    # runs ahead of the host's); the driver gives the first reading's instant on the clock it was handed.
    ahead_s = 1234.5
    sensor = make_sensor(fake, clock=lambda: time.monotonic() + ahead_s)
    try:
        await set_sampling_200us(sensor)
        before = time.monotonic()
        started = await sensor.start_storage(cycle_s=0.002, count=500, timeout_s=5.0)
        after = time.monotonic()
        stored = await sensor.stop_storage(timeout_s=10.0)
    finally:
        await sensor.close()
    assert stored.started_s == started
    assert before + ahead_s <= started <= after + ahead_s
    # the controller's own start (the fake's record, on the host's clock) less the AS echo's time on the wire
    assert abs(started - ahead_s - fake.storage.started_at) < 0.005


async def test_a_storage_left_running_is_stopped_before_the_next_one_starts(fake: FakeLkgController) -> None:
    # A sweep cut short (the robot's feedback lost, the cell stopped) may leave the controller storing,
    # which refuses AQ; the next sweep's start stops it (AP) and clears, instead of failing until it is full.
    sensor = make_sensor(fake)
    try:
        await set_sampling_200us(sensor)
        await sensor.start_storage(cycle_s=0.002, count=5000, timeout_s=5.0)
        await asyncio.sleep(0.1)
        assert fake.storage.storing
        started = await sensor.start_storage(cycle_s=0.002, count=5000, timeout_s=5.0)
        await asyncio.sleep(0.2)
        stored = await sensor.stop_storage(timeout_s=10.0)
    finally:
        await sensor.close()
    tail = sent(fake)
    i = len(tail) - 1 - tail[::-1].index("AS")
    assert tail[i - 3 : i + 1] == ["AQ", "AP", "AQ", "AS"], tail[-10:]
    assert stored.started_s == started and 80 <= len(stored.distances_mm) <= 200  # the second storage's 0.2 s only
