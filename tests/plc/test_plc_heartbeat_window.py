"""The PLC heartbeat's first window opens when the service says it is up (``watch_heartbeat``), not at listen."""

from __future__ import annotations

import asyncio

import pytest
from plc_test_support import MemoryCell, PlcClient, plc_config
from pymodbus.client import AsyncModbusTcpClient

from cellctl.plc import PlcServer
from cellctl.plc.heartbeat import HeartbeatWatch, LinkEvent

pytestmark = pytest.mark.timeout(30)


def test_an_unarmed_watch_reports_no_loss_and_its_first_window_runs_from_arm() -> None:
    w = HeartbeatWatch(timeout_s=1.0, start_s=None)
    assert not w.armed and w.observe(0, 100.0) is None and w.observe(0, 150.0) is None  # silent, unarmed: no loss
    w.arm(150.0)
    assert w.armed and w.observe(0, 150.9) is None  # the window counts from arm, not from construction
    lost = w.observe(0, 151.2)
    assert lost is not None and lost.event is LinkEvent.LOST and lost.silent_for_s == pytest.approx(1.2)
    w.arm(200.0)  # arming again changes nothing
    assert w.observe(0, 200.5) is None
    # a heartbeat seen before arming is reported as started; the window after arming is a full one
    w = HeartbeatWatch(timeout_s=1.0, start_s=None)
    assert w.observe(1, 10.0).event is LinkEvent.STARTED and w.alive
    w.arm(30.0)
    assert w.observe(1, 30.9) is None
    assert w.observe(1, 31.1).event is LinkEvent.LOST


async def test_no_loss_before_watch_heartbeat_then_one_loss_a_timeout_after_it() -> None:
    cell = MemoryCell()
    cfg = plc_config(heartbeat_timeout_s=0.2)
    server = PlcServer(cfg, cell)
    await server.start(watch_heartbeat=False)
    client = AsyncModbusTcpClient("127.0.0.1", port=server.port, timeout=2, retries=1)
    try:
        assert await client.connect()
        plc = PlcClient(client, cfg.float_word_order, unit_id=cfg.unit_id)
        await asyncio.sleep(0.6)  # three timeouts of a silent PLC while the service is still starting
        assert cell.link_events == [] and not (await plc.read_cell())["plc_heartbeat_ok"]
        loop = asyncio.get_running_loop()
        armed_at = loop.time()
        server.watch_heartbeat()
        while not cell.link_events and loop.time() < armed_at + 5.0:
            await asyncio.sleep(0.005)
        assert [e for e, _ in cell.link_events] == ["lost"]
        assert 0.2 <= loop.time() - armed_at < 1.0 and 0.2 <= cell.link_events[0][1] < 1.0
        plc.start_heartbeat(0.03)
        await plc.wait_cell(lambda c: c["plc_heartbeat_ok"], "plc_heartbeat_ok once the PLC beats")
        assert [e for e, _ in cell.link_events] == ["lost", "restored"]
        await plc.stop_heartbeat()
    finally:
        client.close()
        await server.stop()
