"""The pumps of queued events (cellctl.cell.observers.Pumps): at the stop every event queued so far is handled, one a
sink queues on another pump's queue while the stop drains included."""

from __future__ import annotations

import asyncio

from cellctl.cell.observers import Pumps


async def test_an_event_one_sink_queues_for_another_pump_during_the_drain_is_handled() -> None:
    handled: list[str] = []
    machine: asyncio.Queue[str] = asyncio.Queue()
    alarms: asyncio.Queue[str] = asyncio.Queue()

    async def on_machine(ev: str) -> None:
        await asyncio.sleep(0.01)  # its audit entry's write
        handled.append(ev)

    async def on_alarm(ev: str) -> None:
        await asyncio.sleep(0.02)  # the store's write
        handled.append(ev)
        machine.put_nowait(f"hold after {ev}")  # a reaction: the machine goes to Held

    pumps = Pumps("test")
    pumps.start(machine, on_machine)
    pumps.start(alarms, on_alarm)
    alarms.put_nowait("ack")  # the machine's queue is empty as the stop begins
    await pumps.stop(drain_timeout_s=5.0)
    assert handled == ["ack", "hold after ack"]
