"""The PLC handshake's wait for the cell's answer (cellctl.plc.handshake._ask) when the service stops: a call that ends
the stop's cancel with an error of its own (its timeout as the cancel came) ends the handshake cancelled, so no
"the cell did not answer" code is written to the PLC as the service goes down."""

from __future__ import annotations

import asyncio

from cellctl.plc.handshake import _ask
from cellctl.ports import DeviceTimeout


async def test_a_cancel_the_call_turns_into_its_own_error_ends_the_handshake_cancelled() -> None:
    started = asyncio.Event()

    async def answer() -> int:
        started.set()
        try:
            await asyncio.sleep(60)
        except asyncio.CancelledError:
            raise DeviceTimeout("robot", "no answer from the controller in time") from None
        return 7

    task = asyncio.ensure_future(_ask(answer(), 30.0, "result_of(7)", int))
    await started.wait()
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    assert task.cancelled(), task.exception()
