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

