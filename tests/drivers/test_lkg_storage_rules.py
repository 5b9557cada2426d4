"""Data-storage reply rules of the LK-G driver no other test pinned down (a mutation run found them unguarded).

Fact (../shared/reference/keyence_lkg.md A8): ``AN`` answers ``AN,<state 0/1>,<count>`` (JP5000 reads
``iState``, ``iData``): the state is 0 (stopped) or 1 (storing), nothing else. A2: 8N1, ten bits a
character on the wire.
"""

from __future__ import annotations

import asyncio

import pytest

from cellctl.ports import DeviceProtocolError
from keyence_lkg import KeyenceLkgSensor
from keyence_lkg.codec import Reply, parse_line, payload_of
from keyence_lkg.fake import FakeLkgController
from keyence_lkg.storage import STATUS, parse_status


def _fields(reply: bytes) -> tuple[str, ...]:
    line = parse_line(reply)
    assert isinstance(line, Reply)
    return payload_of(STATUS, line)


def test_the_status_reply_is_read() -> None:
    assert STATUS.wire == b"AN\r"
    assert parse_status(_fields(b"AN,1,1200"), "laser") == (True, 1200)
    assert parse_status(_fields(b"AN,0,0"), "laser") == (False, 0)


@pytest.mark.parametrize("reply", [b"AN,2,1200", b"AN,9,5", b"AN,-1,5", b"AN,1", b"AN,1,x"])
def test_a_status_that_is_not_0_or_1_and_a_count_is_a_protocol_error(reply: bytes) -> None:
    with pytest.raises(DeviceProtocolError, match="AN,<0/1>,<count>"):
        parse_status(_fields(reply), "laser")


@pytest.mark.parametrize("baud", [9600, 115200])
async def test_the_start_is_the_echo_less_its_own_time_on_the_wire(baud: int) -> None:
    """The controller starts storing when it has ``AS``; its echo ``AS`` CR (3 characters, 8N1: 10 bits each,
    keyence_lkg.md A2) then takes 30 bit times to reach the PC. The start the driver returns is the echo's
    arrival (the window's late end) less exactly that; the pseudo-terminal ignores the baud rate, the
    driver's arithmetic does not."""
    with FakeLkgController("LK-G5001", lambda: 350.0, display_unit="0.001mm") as fake:
        sensor = KeyenceLkgSensor(
            port=fake.path, dialect="LK-G5001", display_unit="0.001mm", reference_distance_mm=350.0,
            displacement_positive="away_from_head", baud=baud, exchange_timeout_s=1.0, mode_change_timeout_s=1.0,
        )  # fmt: skip
        try:
            started = await sensor.start_storage(cycle_s=0.002, count=50, timeout_s=5.0)
            window = sensor.storage_start_window()
            assert window is not None
            assert [e.command for e in fake.exchanges][-1] == "AS"
            assert window[1] - started == pytest.approx(10.0 * len(b"AS\r") / baud, rel=1e-6)
            await sensor.stop_storage(timeout_s=5.0)
        finally:
            await sensor.close()


async def test_a_read_out_slower_than_the_exchange_timeout_is_waited_for_not_sent_again() -> None:
    """``AO`` answers with every stored reading in one line, nine characters each: at 9600 baud 50 readings
    take half a second on the wire (A2: ten bits a character), far beyond an exchange timeout sized for a
    single value. The driver waits for it (the fake's log, the peer, shows one ``AO``), rather than giving it
    up, resynchronising and asking again."""
    with FakeLkgController("LK-G5001", lambda: 350.0, display_unit="0.001mm") as fake:
        sensor = KeyenceLkgSensor(
            port=fake.path, dialect="LK-G5001", display_unit="0.001mm", reference_distance_mm=350.0,
            displacement_positive="away_from_head", baud=9600, exchange_timeout_s=0.2, mode_change_timeout_s=1.0,
        )  # fmt: skip
        try:
            await sensor.start_storage(cycle_s=0.002, count=50, timeout_s=5.0)
            await asyncio.sleep(0.2)  # let it store its 50 readings (0.1 s)
            fake.delay(0.0, count=2)  # AP and AN at once,
            fake.delay(0.6, count=1)  # then the read-out as slowly as its wire time at 9600 baud would make it
            stored = await sensor.stop_storage(timeout_s=5.0)
            commands = [e.command for e in fake.exchanges]
            assert commands[-3:] == ["AP", "AN", "AO,01"]
            assert commands.count("AO,01") == 1
            assert len(stored.distances_mm) == 50
        finally:
            await sensor.close()
