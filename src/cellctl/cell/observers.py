"""Fan-out of events to observers: plain callbacks and asyncio queues, in order, never blocking."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import Generic, TypeVar

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
