"""The LK-G serial driver against the fake controller over a pseudo-terminal.

Every reply form, every error code of both dialects and every injected fault must end in a
correct reading or a clear error; never a hang (each call is guarded by asyncio.wait_for) and
never a wrong number (a returned reading is checked against the value the fake last sent).
"""

from __future__ import annotations

import asyncio
import itertools
import os
import random
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator
from typing import Any, TypeVar

import pytest

from cellctl.ports import (
    DeviceBusy,
    DeviceDisconnected,
    DeviceError,
    DeviceProtocolError,
    DeviceRejected,
    DeviceTimeout,
    DisplacementSensor,
    DistanceReading,
    LaserStatus,
)
from keyence_lkg import KeyenceLkgSensor, ReconnectPolicy
from keyence_lkg.errors import ERROR_CODES
from keyence_lkg.fake import FakeLkgController
from keyence_lkg.units import DISPLAY_UNITS, ValueKind

DIALECTS = ["LK-G3001", "LK-G5001"]
REF_MM = 350.0
T = TypeVar("T")


async def guarded(call: Awaitable[T], limit_s: float = 5.0) -> T:
    """The call must end on its own; if it has not after ``limit_s`` it hangs and the test fails."""
    try:
        return await asyncio.wait_for(call, limit_s)
    except TimeoutError:
        pytest.fail(f"the driver call did not end within {limit_s} s")


class Ramp:
    """A distance that changes on every call, so a stale reply would show as a wrong number."""

    def __init__(self, start: float = 320.0, step: float = 0.0137) -> None:
        self._count = itertools.count()
        self.start, self.step = start, step

    def __call__(self) -> float:
        return self.start + self.step * (next(self._count) % 3000)


def make_sensor(fake: FakeLkgController, **overrides: Any) -> KeyenceLkgSensor:
    settings: dict[str, Any] = dict(
        port=fake.path,
        dialect=fake.dialect,
        display_unit=fake.unit.name,
        reference_distance_mm=REF_MM,
        displacement_positive="away_from_head",
        exchange_timeout_s=0.1,
        mode_change_timeout_s=0.3,
        reconnect=ReconnectPolicy(attempts=3, interval_s=0.05),
    )
    settings.update(overrides)
    return KeyenceLkgSensor(**settings)


def last_value_sent(fake: FakeLkgController) -> float | None:
    """The displacement (mm) the fake put in its most recent reply."""
    last = fake.exchanges[-1]
    assert last.reply is not None and last.values_mm, f"the fake's last exchange is {last}"
    return last.values_mm[0]


def assert_true_reading(reading: DistanceReading, fake: FakeLkgController) -> None:
    """The reading is the value of the fake's latest reply, mapped to a distance."""
    assert reading.status is LaserStatus.OK
    shown = last_value_sent(fake)
    assert shown is not None
    assert reading.distance_mm == pytest.approx(REF_MM + shown, abs=1e-9)


@pytest.fixture(params=DIALECTS)
def fake(request: pytest.FixtureRequest) -> Iterator[FakeLkgController]:
    with FakeLkgController(request.param, Ramp(), display_unit="0.001mm") as controller:
        yield controller


@pytest.fixture
async def sensor(fake: FakeLkgController) -> AsyncIterator[KeyenceLkgSensor]:
    """For the clean paths: an exchange timeout no loaded test machine reaches."""
    s = make_sensor(fake, exchange_timeout_s=1.0, mode_change_timeout_s=1.0)
    yield s
    await s.close()


@pytest.fixture
async def quick(fake: FakeLkgController) -> AsyncIterator[KeyenceLkgSensor]:
    """For the faults: a short exchange timeout, so lost replies are given up quickly."""
    s = make_sensor(fake)
    yield s
    await s.close()


# --- reply forms ---------------------------------------------------------------------------


async def test_it_is_a_displacement_sensor(sensor: KeyenceLkgSensor) -> None:
    assert isinstance(sensor, DisplacementSensor)


async def test_reads_are_true_values(fake: FakeLkgController, sensor: KeyenceLkgSensor) -> None:
    for _ in range(20):
        reading = await guarded(sensor.read(timeout_s=1.0))
        assert_true_reading(reading, fake)
        assert reading.head == 1
    assert sensor.stats.resyncs == 0 and sensor.stats.timeouts == 0


@pytest.mark.parametrize("dialect", DIALECTS)
@pytest.mark.parametrize("unit", sorted(DISPLAY_UNITS))
async def test_every_display_unit_gives_the_distance(dialect: str, unit: str) -> None:
    fmt = DISPLAY_UNITS[unit]  # type: ignore[index]
    offset = min(3.21, 0.5 * fmt.capacity_mm)
    with FakeLkgController(dialect, lambda: REF_MM - offset, display_unit=unit) as fake:
        s = make_sensor(fake)
        reading = await guarded(s.read(timeout_s=1.0))
        assert reading.distance_mm == pytest.approx(REF_MM - offset, abs=fmt.resolution_mm / 2 + 1e-12)
        await s.close()


@pytest.mark.parametrize("dialect", DIALECTS)
async def test_displacement_sign_toward_the_head(dialect: str) -> None:
    with FakeLkgController(dialect, lambda: 372.5, displacement_positive="toward_head") as fake:
        s = make_sensor(fake, displacement_positive="toward_head")
        assert (await guarded(s.read(timeout_s=1.0))).distance_mm == pytest.approx(372.5)
        fake.set_source(1, lambda: 500.0)
        assert (await guarded(s.read(timeout_s=1.0))).status is LaserStatus.OVER_RANGE_FAR
        fake.set_source(1, lambda: 200.0)
        assert (await guarded(s.read(timeout_s=1.0))).status is LaserStatus.OVER_RANGE_NEAR
        await s.close()


@pytest.mark.parametrize(
    ("source", "status"),
    [
        (lambda: 460.0, LaserStatus.OVER_RANGE_FAR),
        (lambda: 240.0, LaserStatus.OVER_RANGE_NEAR),
        (lambda: None, LaserStatus.OVER_RANGE_FAR),  # no return
        (lambda: LaserStatus.NO_VALUE, LaserStatus.NO_VALUE),
        (lambda: LaserStatus.OVER_RANGE_NEAR, LaserStatus.OVER_RANGE_NEAR),
    ],
)
async def test_over_range_and_no_value_are_statuses(
    fake: FakeLkgController, sensor: KeyenceLkgSensor, source: Callable[[], Any], status: LaserStatus
) -> None:
    fake.set_source(1, source)
    reading = await guarded(sensor.read(timeout_s=1.0))
    assert reading.status is status and reading.distance_mm is None


async def test_beyond_the_display_capacity_is_over_range() -> None:
    with FakeLkgController("LK-G3001", lambda: REF_MM + 12.0, display_unit="0.00001mm") as fake:
        s = make_sensor(fake)
        assert (await guarded(s.read(timeout_s=1.0))).status is LaserStatus.OVER_RANGE_FAR
        await s.close()


async def test_multi_output_reads() -> None:
    sources = {1: lambda: 351.0, 2: lambda: 348.25}
    with FakeLkgController("LK-G3001", sources) as fake:
        s = make_sensor(fake)
        both = await guarded(s.read_displacements(timeout_s=1.0))  # M0
        assert [both[1].mm, both[2].mm] == pytest.approx([1.0, -1.75])
        only2 = await guarded(s.read_displacements([2], timeout_s=1.0))  # M2
        assert list(only2) == [2] and only2[2].mm == pytest.approx(-1.75)
        assert [e.command for e in fake.exchanges] == ["M0", "M2"]
        await s.close()
    sources5 = {1: lambda: 351.0, 2: lambda: 348.25, 3: lambda: None}
    with FakeLkgController("LK-G5001", sources5, out_count=4) as fake:
        s = make_sensor(fake)
        every = await guarded(s.read_displacements(timeout_s=1.0))  # MA
        assert sorted(every) == [1, 2, 3, 4]
        assert every[3].kind is ValueKind.OVER_RANGE_PLUS and every[4].kind is ValueKind.NO_VALUE
        some = await guarded(s.read_displacements([3, 1], timeout_s=1.0))  # MM
        assert list(some) == [3, 1] and some[1].mm == pytest.approx(1.0)
        assert fake.exchanges[-1].command == "MM,101000000000"
        reading = await guarded(s.read(timeout_s=1.0))
        assert reading.distance_mm == pytest.approx(351.0)
        await s.close()


async def test_ping_is_a_round_trip(sensor: KeyenceLkgSensor) -> None:
    duration = await guarded(sensor.ping(timeout_s=1.0))
    assert 0.0 < duration < 1.0


# --- error replies -------------------------------------------------------------------------


@pytest.mark.parametrize(("dialect", "code"), [(d, c) for d in DIALECTS for c in sorted(ERROR_CODES[d])])  # type: ignore[index]
async def test_every_error_code_becomes_device_rejected(dialect: str, code: str) -> None:
    with FakeLkgController(dialect, Ramp()) as fake:
        s = make_sensor(fake)
        count = 3 if code == fake_status_code(dialect) else 1  # a status error: R0, then one retry
        fake.inject_error(code, count)
        with pytest.raises(DeviceRejected) as info:
            await guarded(s.read(timeout_s=1.0))
        assert info.value.code == code
        assert ERROR_CODES[dialect][code].split(" (")[0] in str(info.value)  # type: ignore[index]
        assert dialect in str(info.value)
        assert_true_reading(await guarded(s.read(timeout_s=1.0)), fake)  # and the link is fine
        await s.close()


def fake_status_code(dialect: str) -> str:
    return "01" if dialect == "LK-G3001" else "51"


@pytest.mark.parametrize(("driver_dialect", "controller"), [("LK-G3001", "LK-G5001"), ("LK-G5001", "LK-G3001")])
async def test_a_wrong_dialect_is_reported_not_guessed(driver_dialect: str, controller: str) -> None:
    with FakeLkgController(controller, Ramp()) as fake:
        s = make_sensor(fake, dialect=driver_dialect)
        with pytest.raises(DeviceRejected, match="devices.laser.dialect|command error"):
            await guarded(s.read(timeout_s=1.0))
        await s.close()


async def test_a_wrong_display_unit_is_a_protocol_error_not_a_number(fake: FakeLkgController) -> None:
    s = make_sensor(fake, display_unit="0.0001mm")  # the fake sends 3 decimals
    with pytest.raises(DeviceProtocolError, match="display_unit"):
        await guarded(s.read(timeout_s=2.0))
    await s.close()


# --- modes and settings --------------------------------------------------------------------


async def test_a_controller_left_in_communication_mode_is_brought_back(fake: FakeLkgController, sensor: KeyenceLkgSensor) -> None:
    fake.set_mode("communication")
    assert_true_reading(await guarded(sensor.read(timeout_s=1.0)), fake)
    assert fake.mode == "general"
    assert sensor.stats.mode_recoveries == 1


async def test_settings_inside_communication_mode(fake: FakeLkgController, sensor: KeyenceLkgSensor) -> None:
    out = "1" if fake.dialect == "LK-G3001" else "01"
    status = fake_status_code(fake.dialect)
    with pytest.raises(DeviceRejected) as outside:
        await guarded(sensor.write_setting("CA", "3", timeout_s=1.0))
    assert outside.value.code == status
    async with sensor.communication_mode(timeout_s=1.0):
        assert fake.mode == "communication"
        await guarded(sensor.write_setting("OF", out, "+002000", timeout_s=1.0))
        assert await guarded(sensor.read_setting("OF", out, timeout_s=1.0)) == ("+002.000",)
        await guarded(sensor.write_setting("CA", "4", timeout_s=1.0))
        assert await guarded(sensor.read_setting("CA", timeout_s=1.0)) == ("4",)
        with pytest.raises(DeviceRejected) as bad:
            await guarded(sensor.write_setting("CA", "9" if fake.dialect == "LK-G3001" else "X", timeout_s=1.0))
        assert bad.value.code == ("22" if fake.dialect == "LK-G3001" else "62")
        with pytest.raises(DeviceRejected) as measuring:
            await guarded(sensor.read(timeout_s=1.0))
        assert measuring.value.code == status
    assert fake.mode == "general"
    reading = await guarded(sensor.read(timeout_s=1.0))
    assert_true_reading(reading, fake)
    assert reading.distance_mm is not None and reading.distance_mm > last_raw_distance(fake) + 1.9  # the 2 mm offset


def last_raw_distance(fake: FakeLkgController) -> float:
    shown = last_value_sent(fake)
    assert shown is not None
    return REF_MM + shown - 2.0


async def test_entering_communication_mode_twice_is_tolerated(fake: FakeLkgController, sensor: KeyenceLkgSensor) -> None:
    fake.set_mode("communication")
    async with sensor.communication_mode(timeout_s=1.0):
        assert fake.mode == "communication"
    assert fake.mode == "general"


async def test_the_mode_is_restored_when_the_settings_block_fails(fake: FakeLkgController, sensor: KeyenceLkgSensor) -> None:
    with pytest.raises(RuntimeError, match="operator abort"):
        async with sensor.communication_mode(timeout_s=1.0):
            raise RuntimeError("operator abort")
    assert fake.mode == "general"


# --- faults --------------------------------------------------------------------------------


async def test_a_lost_command_is_recovered(fake: FakeLkgController, quick: KeyenceLkgSensor) -> None:
    await guarded(quick.read(timeout_s=1.0))
    fake.silence(1)
    assert_true_reading(await guarded(quick.read(timeout_s=1.0)), fake)
    assert quick.stats.timeouts >= 1 and quick.stats.resyncs >= 1


async def test_silence_ends_in_a_timeout(fake: FakeLkgController, quick: KeyenceLkgSensor) -> None:
    fake.silence(None)
    with pytest.raises(DeviceTimeout, match="no valid reply"):
        await guarded(quick.read(timeout_s=0.5))
    fake.speak()
    assert_true_reading(await guarded(quick.read(timeout_s=1.0)), fake)


@pytest.mark.parametrize("kind", ["noise_line", "prefix", "replace", "truncate"])
async def test_garbage_is_dropped_and_the_read_recovered(fake: FakeLkgController, quick: KeyenceLkgSensor, kind: str) -> None:
    fake.garble(kind)  # type: ignore[arg-type]
    assert_true_reading(await guarded(quick.read(timeout_s=1.0)), fake)
    assert quick.stats.garbled_lines >= 1 or kind == "truncate"
    assert_true_reading(await guarded(quick.read(timeout_s=1.0)), fake)


async def test_endless_garbage_is_a_protocol_error(fake: FakeLkgController, quick: KeyenceLkgSensor) -> None:
    fake.garble("replace", None)
    with pytest.raises(DeviceProtocolError, match="baud rate"):
        await guarded(quick.read(timeout_s=2.0))
    fake.clear_faults()
    assert_true_reading(await guarded(quick.read(timeout_s=1.0)), fake)


async def test_a_late_reply_is_never_taken_for_the_current_one(fake: FakeLkgController, quick: KeyenceLkgSensor) -> None:
    fake.delay(0.25, count=2)  # two replies arrive after the driver gave up on them
    reading = await guarded(quick.read(timeout_s=2.0))
    assert_true_reading(reading, fake)
    assert quick.stats.late_replies >= 1
    # Every reply that carried a number carried a new one (resync reads of an output with no value,
    # "XXXXXXXX", may repeat under load and are left out).
    measured = [e for e in fake.exchanges if e.values_mm and any(v is not None for v in e.values_mm)]
    assert len({e.values_mm for e in measured}) == len(measured)
    for _ in range(5):
        assert_true_reading(await guarded(quick.read(timeout_s=1.0)), fake)


async def test_slow_replies_within_the_exchange_timeout_are_fine(fake: FakeLkgController) -> None:
    s = make_sensor(fake, exchange_timeout_s=1.0)
    fake.delay(0.1, None)
    for _ in range(3):
        assert_true_reading(await guarded(s.read(timeout_s=1.0)), fake)
    assert s.stats.timeouts == 0
    await s.close()


async def test_unsolicited_lines_are_ignored(fake: FakeLkgController, sensor: KeyenceLkgSensor) -> None:
    await guarded(sensor.read(timeout_s=1.0))
    fake.send_unsolicited("TG,1,+001.000")
    fake.delay(0.02)
    assert_true_reading(await guarded(sensor.read(timeout_s=1.0)), fake)


async def test_concurrent_callers_take_turns(fake: FakeLkgController, sensor: KeyenceLkgSensor) -> None:
    readings = await guarded(asyncio.gather(*(sensor.read(timeout_s=2.0) for _ in range(12))))
    values = [r.distance_mm for r in readings]
    sent = [REF_MM + e.values_mm[0] for e in fake.exchanges if e.values_mm and e.values_mm[0] is not None]
    assert values == pytest.approx(sent)  # one command in flight: every reply answered its own read
    assert sensor.stats.late_replies == 0


async def test_a_ping_while_a_long_exchange_holds_the_line_says_busy_and_the_watchdog_misses_nothing(
    fake: FakeLkgController, sensor: KeyenceLkgSensor
) -> None:
    """A storage read-out holds the serial line for seconds (9 characters a reading at 115200 Bd): the watchdog's ping
    cannot be sent meanwhile, which says nothing of the device; a silent device on a free line is still a miss."""
    from cellctl.cell.alarms import AlarmManager
    from cellctl.cell.watchdog import DeviceWatchdog, LinkState, WatchdogSettings

    am = AlarmManager()
    wd = DeviceWatchdog(am, defaults=WatchdogSettings(period_s=0.2, timeout_s=0.15, miss_threshold=1))
    wd.add("laser", sensor)
    fake.delay(0.8)  # the next reply comes late: the line is held the whole time
    long = asyncio.ensure_future(sensor.read(timeout_s=2.0))
    await asyncio.sleep(0.05)
    with pytest.raises(DeviceBusy, match="busy") as busy:
        await guarded(sensor.ping(timeout_s=0.15))
    assert isinstance(busy.value, DeviceTimeout)  # to a caller of the port it is a timeout like any other
    for _ in range(3):
        h = (await guarded(wd.check_once()))["laser"]
    assert_true_reading(await guarded(long), fake)
    assert (h.link, h.misses) == (LinkState.UNKNOWN, 0) and am.active() == []
    fake.silence(None)  # the line free, the controller silent: the ping itself times out
    h = (await guarded(wd.check_once()))["laser"]
    assert h.link == LinkState.LOST and "busy" not in (h.last_error or "")


@pytest.mark.parametrize("seed", [1, 2])
async def test_random_faults_never_give_a_wrong_number(fake: FakeLkgController, seed: int) -> None:
    rng = random.Random(seed)
    s = make_sensor(fake)
    faults = ["none", "silence", "noise_line", "prefix", "replace", "truncate", "late", "tg", "error"]
    for _ in range(30):
        fault = rng.choice(faults)
        if fault == "silence":
            fake.silence(1)
        elif fault in ("noise_line", "prefix", "replace", "truncate"):
            fake.garble(fault)  # type: ignore[arg-type]
        elif fault == "late":
            fake.delay(rng.uniform(0.11, 0.25))
        elif fault == "tg":
            fake.send_unsolicited("TG,1,+000.500")
        elif fault == "error":
            fake.inject_error("88")
        try:
            reading = await guarded(s.read(timeout_s=1.5))
        except DeviceRejected as exc:
            assert fault == "error" and exc.code == "88"
            continue
        assert fault != "error"
        assert_true_reading(reading, fake)
    await s.close()


# --- the port going away -------------------------------------------------------------------


async def test_the_adapter_comes_back_within_the_call(fake: FakeLkgController) -> None:
    s = make_sensor(fake, reconnect=ReconnectPolicy(attempts=40, interval_s=0.05))
    await guarded(s.read(timeout_s=1.0))
    fake.vanish()
    loop = asyncio.get_running_loop()
    back = loop.run_in_executor(None, lambda: (__import__("time").sleep(0.3), fake.reappear()))
    assert_true_reading(await guarded(s.read(timeout_s=3.0)), fake)
    await back
    assert s.stats.reconnects == 1
    await s.close()


async def test_the_adapter_stays_away(fake: FakeLkgController, quick: KeyenceLkgSensor) -> None:
    await guarded(quick.read(timeout_s=1.0))
    fake.vanish()
    with pytest.raises(DeviceDisconnected, match="did not come back after 3 attempt"):
        await guarded(quick.read(timeout_s=2.0))
    fake.reappear()  # plugged back later: the next call reconnects
    assert_true_reading(await guarded(quick.read(timeout_s=1.0)), fake)
    assert quick.stats.reconnects == 1


async def test_a_port_that_never_existed(tmp_path: Any) -> None:
    s = KeyenceLkgSensor(
        port=os.fspath(tmp_path / "ttyUSB9"), dialect="LK-G3001", display_unit="0.001mm",
        reference_distance_mm=REF_MM, displacement_positive="away_from_head",
        reconnect=ReconnectPolicy(attempts=2, interval_s=0.01),
    )
    with pytest.raises(DeviceDisconnected, match="ttyUSB9.*devices.laser.port"):
        await guarded(s.read(timeout_s=1.0))


async def test_close_twice_then_calls_are_refused(fake: FakeLkgController, sensor: KeyenceLkgSensor) -> None:
    await guarded(sensor.read(timeout_s=1.0))
    await sensor.close()
    await sensor.close()
    with pytest.raises(DeviceDisconnected, match="closed"):
        await guarded(sensor.read(timeout_s=1.0))


# --- arguments -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ({"dialect": "LK-G"}, "never guessed"),
        ({"display_unit": "mm"}, "display unit"),
        ({"reference_distance_mm": float("nan")}, "reference_distance_mm"),
        ({"displacement_positive": "up"}, "displacement_positive"),
        ({"baud": 14400}, "baud"),
        ({"output": 3}, "1..2"),
        ({"exchange_timeout_s": 0.0}, "exchange_timeout_s"),
    ],
)
def test_bad_settings_are_refused(override: dict[str, Any], message: str) -> None:
    settings: dict[str, Any] = dict(
        port="/dev/null", dialect="LK-G3001", display_unit="0.001mm", reference_distance_mm=REF_MM,
        displacement_positive="away_from_head",
    )
    settings.update(override)
    with pytest.raises(ValueError, match=message):
        KeyenceLkgSensor(**settings)


async def test_a_bad_timeout_is_refused(sensor: KeyenceLkgSensor) -> None:
    for bad in (0.0, -1.0, float("inf"), float("nan")):
        with pytest.raises(ValueError, match="timeout_s"):
            await sensor.read(timeout_s=bad)


async def test_errors_are_device_errors_naming_the_device(fake: FakeLkgController) -> None:
    s = make_sensor(fake, name="LDS")
    fake.silence(None)
    with pytest.raises(DeviceError, match="^LDS: "):
        await guarded(s.read(timeout_s=0.3))
    await s.close()


@pytest.mark.parametrize("named_by", ["command", "setting"])
async def test_a_refused_setting_is_rejected_at_once_whichever_header_its_error_has(named_by: str) -> None:
    """The manual heads an error with the main command (ER,SW,62); the ISIS emulator, built against the real
    controller, with the setting (ER,CF,62). Both are the answer to SW: one exchange and its code, not a time-out
    after resending it (the reference notes, keyence_lkg.md B4: accept either)."""
    with FakeLkgController("LK-G5001", Ramp()) as fake:
        fake.setting_errors_name_the_setting = named_by == "setting"
        s = make_sensor(fake, exchange_timeout_s=0.3)
        async with s.communication_mode(timeout_s=2.0):
            with pytest.raises(DeviceRejected) as info:
                await guarded(s.write_setting("CF", "0001000", "12", timeout_s=1.5))  # cycle code 12: out of range
        assert info.value.code == "62"
        sent = [e for e in fake.exchanges if e.command.startswith("SW")]
        assert [e.reply for e in sent] == ["ER,SW,62" if named_by == "command" else "ER,CF,62"]
        await s.close()
