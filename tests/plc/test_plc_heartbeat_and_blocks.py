"""Heartbeats both ways, and the PLC and cell blocks kept apart on the wire."""

from __future__ import annotations

import asyncio
import errno
import logging
import socket
import time

import pytest
from plc_test_support import MemoryCell, plc_config, running_cell
from pymodbus.client import AsyncModbusTcpClient

from cellctl.cell.tags import PackMLState, UnitMode
from cellctl.plc import PlcServer
from cellctl.plc.heartbeat import HeartbeatWatch, LinkEvent
from cellctl.plc.process_image import CellImage
from cellctl.plc.register_map import CELL_BLOCK, MAP_VERSION, PLC_BLOCK

pytestmark = pytest.mark.timeout(30)


async def _wait(predicate, what: str, timeout_s: float = 5.0) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout_s
    while not predicate():
        if loop.time() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        await asyncio.sleep(0.005)


def test_heartbeat_watch_reports_loss_once_and_recovery_once() -> None:
    w = HeartbeatWatch(timeout_s=1.0, start_s=100.0)
    assert w.observe(0, 100.5) is None and not w.alive  # nothing seen yet, not yet too long
    lost = w.observe(0, 101.2)  # never started within the timeout
    assert lost is not None and lost.event is LinkEvent.LOST and lost.silent_for_s == pytest.approx(1.2)
    assert w.observe(0, 105.0) is None  # reported once
    back = w.observe(1, 105.1)
    assert back is not None and back.event is LinkEvent.RESTORED and w.alive
    assert w.observe(2, 105.9) is None and w.observe(2, 106.8) is None and w.alive
    lost = w.observe(2, 107.0)  # unchanged since 105.9: 1.1 s
    assert lost is not None and lost.event is LinkEvent.LOST and not w.alive
    assert w.observe(1, 107.1).event is LinkEvent.RESTORED  # a toggle back counts as a change
    # A heartbeat that starts within the timeout is reported once, as started.
    w = HeartbeatWatch(timeout_s=1.0, start_s=0.0)
    started = w.observe(1, 0.5)
    assert started is not None and started.event is LinkEvent.STARTED and w.alive
    assert w.observe(2, 0.6) is None
    with pytest.raises(ValueError, match="timeout"):
        HeartbeatWatch(timeout_s=0.0, start_s=0.0)


async def test_plc_heartbeat_loss_is_detected_and_recovery_reported() -> None:
    cell = MemoryCell()
    async with running_cell(cell, heartbeat_timeout_s=0.3) as (server, plc):
        plc.start_heartbeat(0.03)
        await plc.wait_cell(lambda c: c["plc_heartbeat_ok"], "plc_heartbeat_ok")
        await asyncio.sleep(0.5)  # beating: reported up once, no loss
        assert cell.link_events == [("restored", 0.0)] and server.plc_link_alive
        await plc.stop_heartbeat()
        await _wait(lambda: len(cell.link_events) == 2, "PLC heartbeat lost")
        event, silent = cell.link_events[1]
        assert event == "lost" and silent > 0.3
        c = await plc.read_cell()
        assert not c["plc_heartbeat_ok"] and not server.plc_link_alive
        # a PLC that keeps writing the same value is still silent
        await plc.write(plc_heartbeat=plc.heartbeat)
        await asyncio.sleep(0.1)
        assert len(cell.link_events) == 2
        plc.start_heartbeat(0.03)
        await _wait(lambda: len(cell.link_events) == 3, "PLC heartbeat restored")
        assert cell.link_events[2][0] == "restored"
        await plc.wait_cell(lambda c: c["plc_heartbeat_ok"], "plc_heartbeat_ok again")


async def test_a_plc_that_never_beats_is_reported_lost() -> None:
    cell = MemoryCell()
    async with running_cell(cell, heartbeat_timeout_s=0.2) as (_server, _plc):
        await _wait(lambda: cell.link_events, "PLC heartbeat lost")
        assert cell.link_events[0][0] == "lost"


async def test_cell_heartbeat_counts_and_stops_when_the_cell_does_not_answer() -> None:
    cell = MemoryCell()
    async with running_cell(cell, cell_heartbeat_period_s=0.02) as (_server, plc):
        a = (await plc.read_cell())["cell_heartbeat"]
        await asyncio.sleep(0.2)
        b = (await plc.read_cell())["cell_heartbeat"]
        assert b - a >= 3  # about 10 expected; far fewer would still prove it counts
        cell.status_raises = True
        await asyncio.sleep(0.05)
        frozen = (await plc.read_cell())["cell_heartbeat"]
        await asyncio.sleep(0.15)
        assert (await plc.read_cell())["cell_heartbeat"] == frozen
        cell.status_raises = False
        await plc.wait_cell(lambda c: c["cell_heartbeat"] != frozen, "cell heartbeat again")


async def test_plc_writes_into_the_cell_block_are_refused_and_change_nothing() -> None:
    cell = MemoryCell()
    async with running_cell(cell) as (server, plc):
        client = plc.client
        await plc.run_cycle(21, 1, 2)
        await plc.wait_cell(lambda c: c["ready"], "ready")  # settled, so nothing should change now
        before = await client.read_holding_registers(CELL_BLOCK.start, count=CELL_BLOCK.size, device_id=1)
        attempts = [
            lambda: client.write_registers(CELL_BLOCK.start + 8, [0xDEAD, 0xBEEF], device_id=1),  # FC16
            lambda: client.write_register(CELL_BLOCK.start + 3, 6, device_id=1),  # FC6 state_current
            lambda: client.readwrite_registers(read_address=0, read_count=2, device_id=1,
                                               write_address=CELL_BLOCK.start + 7, values=[0xFFFF]),  # FC23
            lambda: client.mask_write_register(address=CELL_BLOCK.start + 15, and_mask=0, or_mask=7,
                                               device_id=1),  # FC22 error_code
        ]
        for attempt in attempts:
            rr = await attempt()
            assert rr.isError() and rr.exception_code == 2, rr
        # across the gap between the blocks: the addresses do not exist
        rr = await client.write_registers(PLC_BLOCK.end - 1, [0] * (CELL_BLOCK.start - PLC_BLOCK.end + 2),
                                          device_id=1)
        assert rr.isError() and rr.exception_code == 2
        # coils and input registers are not part of the interface
        rr = await client.write_coil(CELL_BLOCK.start, True, device_id=1)
        assert rr.isError() and rr.exception_code == 1
        rr = await client.read_input_registers(CELL_BLOCK.start, count=2, device_id=1)
        assert rr.isError() and rr.exception_code == 1

        after = await client.read_holding_registers(CELL_BLOCK.start, count=CELL_BLOCK.size, device_id=1)
        skip = {2, CELL_BLOCK.register("refused_write_count").address - CELL_BLOCK.start}  # heartbeat, count
        assert [w for i, w in enumerate(after.registers) if i not in skip] == \
               [w for i, w in enumerate(before.registers) if i not in skip]
        assert server.refused_writes == 5  # the four, and the write across the gap: it reached into the cell block
        await plc.wait_cell(lambda c: c["refused_write_count"] == 5, "refused_write_count = 5")
        # the PLC block stays writable, and the cell never wrote into it
        assert (await plc.read_plc_block())[10] == 0  # cycle_request as the PLC left it
        await plc.write(recipe_id=3)
        assert (await plc.read_plc_block())[5] == 3


async def test_a_write_reaching_into_the_cell_block_from_below_is_refused_counted_and_writes_nothing() -> None:
    cell = MemoryCell()
    async with running_cell(cell) as (server, plc):
        client = plc.client
        await plc.write(recipe_id=3)
        plc_before = await plc.read_plc_block()
        spans = [(CELL_BLOCK.start - 2, 4), (PLC_BLOCK.end - 2, CELL_BLOCK.start - PLC_BLOCK.end + 4),
                 (PLC_BLOCK.start, CELL_BLOCK.start - PLC_BLOCK.start + 2)]  # from the gap, the PLC block's end, its start
        for k, (address, n) in enumerate(spans, start=1):
            rr = await client.write_registers(address, [0xBEEF] * n, device_id=1)
            assert rr.isError() and rr.exception_code == 2, (address, n, rr)
            await plc.wait_cell(lambda c, k=k: c["refused_write_count"] == k, f"refused_write_count = {k}")
        assert server.refused_writes == len(spans)
        assert await plc.read_plc_block() == plc_before  # nothing of the PLC block they spanned was written either
        rr = await client.write_registers(PLC_BLOCK.end - 2, [0, 0, 0], device_id=1)  # into the gap alone: not counted
        assert rr.isError() and rr.exception_code == 2
        await asyncio.sleep(0.1)
        assert server.refused_writes == len(spans)


async def test_another_unit_id_gets_exception_11_without_a_traceback_and_changes_nothing(
        caplog: pytest.LogCaptureFixture) -> None:
    cell = MemoryCell()
    caplog.set_level(logging.DEBUG)
    async with running_cell(cell) as (server, plc):  # unit id 1
        client = plc.client
        before = await plc.read_plc_block()
        for device_id in (0, 2, 7, 247):
            replies = [
                await client.read_holding_registers(CELL_BLOCK.start, count=2, device_id=device_id),  # FC3
                await client.write_registers(PLC_BLOCK.start, [5, 6], device_id=device_id),  # FC16
                await client.write_register(5, 9, device_id=device_id),  # FC6
            ]
            for rr in replies:
                assert rr.isError() and rr.exception_code == 11, (device_id, rr)
        assert await plc.read_plc_block() == before  # nothing was written
        assert server.other_unit_requests == {0: 3, 2: 3, 7: 3, 247: 3}
        rr = await client.read_holding_registers(CELL_BLOCK.start, count=2, device_id=1)
        assert not rr.isError() and rr.registers == list(MAP_VERSION)  # its own unit id still answers
    errors = [r for r in caplog.records if r.levelno >= logging.ERROR or r.exc_info or "Traceback" in r.getMessage()]
    assert errors == [], [r.getMessage() for r in errors]
    warned = [r.getMessage() for r in caplog.records if r.name == "cellctl.plc.server" and r.levelno == logging.WARNING]
    assert len(warned) == 4 and "unit id 7" in " ".join(warned) and "[plc] unit_id" in warned[0]


@pytest.mark.parametrize("occupant", ["listening", "bound", "listening with SO_REUSEADDR"])
async def test_a_taken_port_fails_the_start_promptly_and_names_the_setting(occupant: str) -> None:
    with socket.socket() as other:  # another program has the port
        if "REUSEADDR" in occupant:
            other.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        other.bind(("127.0.0.1", 0))
        if occupant.startswith("listening"):
            other.listen()
        port = other.getsockname()[1]
        server = PlcServer(plc_config(port=port), MemoryCell())
        t0 = time.monotonic()
        with pytest.raises(OSError, match=r"\[plc\] port") as raised:
            await asyncio.wait_for(server.start(), 10.0)
        assert time.monotonic() - t0 < 2.0
        assert raised.value.errno == errno.EADDRINUSE and f"127.0.0.1:{port}" in str(raised.value)
        assert not server.running
    # the port free again: the same server object starts on it
    await server.start()
    try:
        assert server.port == port
    finally:
        await server.stop()


async def test_a_host_that_is_not_this_machine_fails_the_start_naming_the_setting() -> None:
    server = PlcServer(plc_config(host="192.0.2.1"), MemoryCell())  # TEST-NET-1: never a local address
    with pytest.raises(OSError, match=r"\[plc\] host"):
        await asyncio.wait_for(server.start(), 10.0)
    assert not server.running


async def test_the_first_read_after_a_start_already_shows_the_cells_state() -> None:
    cell = MemoryCell()
    cell.state = PackMLState.ABORTED  # as the cell starts
    # A slow scan: the scan loop's first round comes 1 s after the start; the image must not wait for it.
    async with running_cell(cell, scan_period_s=1.0, heartbeat_timeout_s=3.0, cell_heartbeat_period_s=1.0) as (_s, plc):
        first = await plc.read_cell()
        assert first["state_current"] == PackMLState.ABORTED and first["unit_mode_current"] == UnitMode.PRODUCTION
        assert (first["map_version_major"], first["map_version_minor"]) == MAP_VERSION and not first["ready"]


async def test_unit_id_zero_answers_every_unit_id() -> None:
    cell = MemoryCell()
    async with running_cell(cell, unit_id=0) as (_server, plc):
        for device_id in (1, 7, 247):
            rr = await plc.client.read_holding_registers(CELL_BLOCK.start, count=2, device_id=device_id)
            assert not rr.isError() and rr.registers == list(MAP_VERSION)


def test_the_cell_image_refuses_plc_registers_and_bad_values() -> None:
    image = CellImage()
    with pytest.raises(KeyError, match="PLC block"):
        image.update(cycle_req_id=5)
    with pytest.raises(KeyError, match="no bit 'bogus'"):
        image.update(cycle_flags={"bogus": True})
    with pytest.raises(ValueError, match="dx_mm"):
        image.update(dx_mm=float("inf"))
    with pytest.raises(ValueError, match="state_current"):
        image.update(state_current=70000, error_code=1)
    assert image.value("error_code") == 0  # all or nothing
    image.update(cycle_flags={"busy": True, "done": True})
    image.update(cycle_flags={"busy": False})
    assert image.flag("cycle_flags", "done") and not image.flag("cycle_flags", "busy")


async def test_start_stop_and_clear_errors() -> None:
    cell = MemoryCell()
    server = PlcServer(plc_config(), cell)
    await server.start()
    port = server.port
    with pytest.raises(RuntimeError, match="already running"):
        await server.start()
    taken = PlcServer(plc_config(port=port), MemoryCell())
    with pytest.raises(OSError, match="cannot listen"):
        await taken.start()
    await server.stop()
    assert not server.running
    client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=0.5, retries=0, reconnect_delay=0)
    assert not await client.connect()
    client.close()
    with pytest.raises(TypeError, match="does not implement CellFacade"):
        PlcServer(plc_config(), object())  # type: ignore[arg-type]
