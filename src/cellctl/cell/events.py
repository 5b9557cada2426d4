"""A small fan-out of cell events (state changes, alarms, cycle progress) for SSE and the dashboard."""

from __future__ import annotations

import asyncio
import itertools
import time
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class CellEvent:
    """One event: ``kind`` names it (``state``, ``alarm``, ``cycle``, ``step``), ``data`` is JSON-ready."""

    seq: int
    kind: str
    data: dict[str, Any]
    at: float = field(default_factory=time.time)


class EventHub:
    """Publish to every subscriber's queue; a slow subscriber loses its oldest events, never blocks others."""

    def __init__(self, queue_size: int = 256) -> None:
        self._queues: set[asyncio.Queue[CellEvent]] = set()
        self._size = queue_size
        self._seq = itertools.count(1)
        self.closing = False

    def close(self) -> None:
        """The service is stopping: every subscriber gets a last ``shutdown`` event and its stream ends."""
        if not self.closing:
            self.publish("shutdown", {})
            self.closing = True

    def publish(self, kind: str, data: dict[str, Any]) -> CellEvent:
        event = CellEvent(next(self._seq), kind, data)
        for q in list(self._queues):
            if q.full():
                q.get_nowait()
            q.put_nowait(event)
        return event

    def subscribe(self) -> asyncio.Queue[CellEvent]:
        q: asyncio.Queue[CellEvent] = asyncio.Queue(self._size)
        self._queues.add(q)
        return q

    def unsubscribe(self, q: asyncio.Queue[CellEvent]) -> None:
        self._queues.discard(q)

    @property
    def subscribers(self) -> int:
        return len(self._queues)
