"""A service's stop ends its background tasks even when one of them swallowed its cancellation."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from service_test_support import AUTH, api_client, build_service, sim_config, to_execute


async def test_stop_ends_a_pump_whose_sink_swallowed_the_cancel(tmp_path: Path) -> None:
    # Python 3.11's asyncio.wait_for returns its call's result when the cancel lands as the call completes; a
    # pump whose sink sat in such a call runs on to its queue. Here the audit sink swallows the first cancel so.
    service = await build_service(sim_config(), workdir=tmp_path)
    await service.start()
    entered, stuck, swallowed = asyncio.Event(), asyncio.Event(), [0]

    async def sink(*_: Any, **__: Any) -> None:
        entered.set()
        try:
            await stuck.wait()  # the store's write never comes back
        except asyncio.CancelledError:
            swallowed[0] += 1
            if swallowed[0] > 1:  # then as asyncio would: a test that fails still ends
                raise

    try:
        async with api_client(service) as client:
            await to_execute(client)
            service.orchestrator.store.append_machine_event = sink  # type: ignore[method-assign]
            r = await client.post("/commands/hold", headers=AUTH)  # a state change: the pump now waits in the sink
            assert r.status_code == 200, r.text
            await asyncio.wait_for(entered.wait(), timeout=10.0)
    finally:
        stopping = asyncio.ensure_future(service.stop())
        done, _ = await asyncio.wait({stopping}, timeout=10.0)
    assert stopping in done, "stop() still waits for a pump that went on after its cancel"  # before the mend: for ever
    assert swallowed[0] >= 1  # a cancel was lost



async def test_stop_waits_for_a_cut_sweeps_clean_up_before_the_devices_close(tmp_path: Path, monkeypatch: Any) -> None:
    # A sweep cut short by the service's stop ends the pose stream and the laser's storage, shielded, before
    # the devices close. Here that clean-up takes 1.5 s; stop() must not return before it has ended (a stop that
    # cancels again every half second cut it loose: it returned after 0.5 s and the clean-up ran on unawaited).
    from cellctl.cell import sweep

    moving, cleaned = asyncio.Event(), asyncio.Event()
    real_leave = sweep._leave_nothing_running

    async def long_path(run: Any, step: Any, moves: Any, stream: Any) -> None:
        moves.close()  # the sweep's moves never end: the stop comes mid-path
        moving.set()
        await asyncio.Event().wait()

    async def slow_leave(*args: Any) -> None:
        await asyncio.sleep(1.5)
        await real_leave(*args)
        cleaned.set()

    monkeypatch.setattr(sweep, "_supervised", long_path)
    monkeypatch.setattr(sweep, "_leave_nothing_running", slow_leave)
    config = sim_config(devices={"laser": {"kind": "sim"}, "robot": {"kind": "sim"}}, **{"process.align": {"mode": "on_the_fly"}})
    service = await build_service(config, workdir=tmp_path)
    await service.start()
    try:
        async with api_client(service) as client:
            await to_execute(client)
            r = await client.post(
                "/cycle", json={"recipe": "side-window", "part_id": "P-STOP-1"}, headers={**AUTH, "Idempotency-Key": "stop-1"}
            )
            assert r.status_code in (200, 201, 202), r.text
            await asyncio.wait_for(moving.wait(), timeout=20.0)
    finally:
        await asyncio.wait_for(service.stop(), timeout=20.0)
    assert cleaned.is_set(), "stop() returned while the cut sweep's clean-up still ran"
