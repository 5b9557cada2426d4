"""EGM position stream against the fake controller: the robot's STOP ends the stream on the controller, and the
datagrams it sent before its answer that are still on their way are collected as at STREAM 0. Truth is the fake's
own count of the datagrams it sent, never the driver's objects."""

from __future__ import annotations

import asyncio
import contextlib
import queue
import threading
import time
from typing import Any

import pytest

from _abb_testkit import fake_and_robot
from abb_robot.fake import FakeController

pytestmark = pytest.mark.realtime  # the fake streams on the host's clock

LATENCY_S = 0.02  # the network's: five datagrams at 250 Hz are on their way at any instant


class _Late:
    """Stands in for the fake's EGM socket: every datagram arrives ``LATENCY_S`` after it was sent (when: ``sent_at``),
    in the order sent, through one delivery thread (a timer thread a datagram starts late under load, out of order)."""

    def __init__(self, sock: Any) -> None:
        self.sock, self.sent_at = sock, []
        self._due: queue.SimpleQueue[tuple[float, bytes, tuple[str, int]]] = queue.SimpleQueue()
        threading.Thread(target=self._deliver, daemon=True).start()

    def sendto(self, data: bytes, addr: tuple[str, int]) -> int:
        now = time.monotonic()
        self.sent_at.append(now)
        self._due.put((now + LATENCY_S, data, addr))
        return len(data)

    def _deliver(self) -> None:
        while True:
            due, data, addr = self._due.get()
            time.sleep(max(0.0, due - time.monotonic()))
            with contextlib.suppress(OSError):  # the fake's socket closed at the end of the test
                self.sock.sendto(data, addr)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.sock, name)


def _delay_datagrams(fake: FakeController) -> _Late:
    runner = fake.egm.stream  # type: ignore[union-attr]
    late = _Late(runner._args[0])
    runner._args = (late, *runner._args[1:])
    return late


async def test_a_stop_collects_the_datagrams_still_on_their_way() -> None:
    async with fake_and_robot(egm=True, fake_kw={"time_scale": 1.0}, robot_kw={"egm_isolation": "thread"}) as (fake, robot):
        late = _delay_datagrams(fake)
        await robot.start_stream(timeout_s=5.0)
        await asyncio.sleep(0.4)
        asked = time.monotonic()
        await robot.stop(timeout_s=5.0)  # the controller's STOP ends the stream (the module's EGMStreamStop)
        samples = await robot.stop_stream(timeout_s=2.0)
        sent = fake.egm_stream_stats
        assert sent is not None and sent.dropped_out == 0
        before = sum(t < asked for t in late.sent_at)  # sent before the STOP was asked for: on their way at most
        received = robot.stream_stats.received
        assert before > 50 and before <= received <= len(late.sent_at), (before, received, len(late.sent_at))
        assert len(samples) == received
