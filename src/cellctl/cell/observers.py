"""Fan-out of events to observers (plain callbacks and asyncio queues, in order, never blocking), and the pumps that
hand a queue's events to an async sink."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable
from typing import Any, Generic, TypeVar

from cellctl.cell.cancel import cancel_until_done

_log = logging.getLogger(__name__)

T = TypeVar("T")


class Fanout(Generic[T]):
    """Deliver each event to every callback (synchronously, in order) and every queue.

    A callback that raises is logged and skipped; the others still get the event. A queue made
    with ``maxsize`` > 0 drops its oldest event when full (a slow reader must not stall the cell);
    :attr:`dropped` counts those drops per queue.
    """

    def __init__(self, what: str) -> None:
        self._what = what
        self._callbacks: list[Callable[[T], object]] = []
        self._queues: list[asyncio.Queue[T]] = []
        self.dropped: dict[int, int] = {}

    def subscribe(self, callback: Callable[[T], object]) -> Callable[[], None]:
        """Call ``callback(event)`` for every event; returns a function that unsubscribes."""
        self._callbacks.append(callback)

        def unsubscribe() -> None:
            if callback in self._callbacks:
                self._callbacks.remove(callback)

        return unsubscribe

    def subscribe_queue(self, maxsize: int = 0) -> asyncio.Queue[T]:
        """A queue receiving every event (unbounded by default)."""
        q: asyncio.Queue[T] = asyncio.Queue(maxsize)
        self._queues.append(q)
        self.dropped[id(q)] = 0
        return q

    def unsubscribe_queue(self, queue: asyncio.Queue[T]) -> None:
        self._queues = [q for q in self._queues if q is not queue]
        self.dropped.pop(id(queue), None)

    def publish(self, event: T) -> None:
        for cb in list(self._callbacks):
            try:
                cb(event)
            except Exception:
                _log.exception("%s observer %r failed", self._what, cb)
        for q in self._queues:
            if q.full():
                q.get_nowait()
                self.dropped[id(q)] += 1
            q.put_nowait(event)


class Pumps:
    """Tasks that each hand a queue's events, in order, to an async sink (the store's records of alarms and machine
    events). Stopping lets them finish what was queued first: an acknowledgement made as the service stops is stored."""

    DRAIN_POLL_S = 0.005

    def __init__(self, what: str) -> None:
        self._what = what
        self._running: list[tuple[asyncio.Queue[Any], asyncio.Task[None]]] = []
        self._busy = 0  # events taken from a queue and not yet handled

    def start(self, queue: asyncio.Queue[T], sink: Callable[[T], Awaitable[object]]) -> None:
        self._running.append((queue, asyncio.create_task(self._pump(queue, sink))))

    async def _pump(self, queue: asyncio.Queue[T], sink: Callable[[T], Awaitable[object]]) -> None:
        while True:
            event = await queue.get()
            self._busy += 1
            try:
                await sink(event)
            except Exception:  # a bad event must not stop the pump; it is logged with its trace
                _log.exception("%s: handling %r failed", self._what, event)
            finally:
                self._busy -= 1

    def _idle(self) -> bool:
        """Every queue empty and no event in hand, at once (a sink may queue an event on another pump's queue)."""
        return self._busy == 0 and all(q.empty() for q, t in self._running if not t.done())

    async def stop(self, *, drain_timeout_s: float) -> None:
        """Wait up to ``drain_timeout_s`` (s) for the events queued so far to be handled, then end the pumps."""
        loop = asyncio.get_running_loop()
        end = loop.time() + drain_timeout_s
        while not self._idle() and loop.time() < end:
            await asyncio.sleep(self.DRAIN_POLL_S)
        if not self._idle():
            left = sum(q.qsize() for q, _ in self._running) + self._busy
            _log.error("%s: %d event(s) left unhandled after %.1f s at the stop", self._what, left, drain_timeout_s)
        await cancel_until_done([t for _, t in self._running])  # a sink may swallow one cancel (Python 3.11's wait_for)
        self._running.clear()
