"""The outbox as the MQTT code uses it: queue messages in the store, say what the bound dropped, wake the publisher.

The rows and the bound live in the store (:mod:`cellctl.store.outbox`); this adds what the
service needs around them: a WARNING for every dropped message, the pending and dropped figures
for /status without a store call, and an event the publisher waits on.

"Dropped" means "never sent": the publisher reads rows in batches, so before it sends one it
claims it (:meth:`Outbox.claim`): a row the bound dropped since the batch was read is skipped, and the
claimed row (in flight until :meth:`Outbox.sent`) is one the bound never drops. A lock orders the
claims, the batch reads and the enqueues, so no drop slips between a claim and its check.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Sequence
from dataclasses import dataclass

from cellctl.store import AsyncCellStore
from cellctl.store.outbox import RESULT_KIND, Enqueued, OutboxMessage, OutboxRow

log = logging.getLogger(__name__)


@dataclass
class OutboxFigures:
    """What /status shows of the outbox (as of the last enqueue or acknowledgement)."""

    pending: int = 0
    queued: int = 0  # messages queued since the service started
    dropped: int = 0  # dropped since the service started
    dropped_results: int = 0
    dropped_total: int = 0  # in the store's whole life
    dropped_results_total: int = 0


class Outbox:
    """Queue messages for the broker; the publisher waits on :attr:`wake`."""

    def __init__(self, store: AsyncCellStore, max_messages: int) -> None:
        self.store = store
        self.max_messages = max_messages
        self.wake = asyncio.Event()
        self.figures = OutboxFigures()
        self.in_flight: int | None = None  # the row being sent: never dropped
        self._gone: set[int] = set()  # rows dropped since the publisher read its batch
        self._lock = asyncio.Lock()

    async def load(self) -> None:
        """Read the pending and dropped counts the store holds (at start)."""
        c = await self.store.outbox_counts()
        self.figures.pending = c.pending
        self.figures.dropped_total, self.figures.dropped_results_total = c.dropped_total, c.dropped_results

    async def put(self, messages: Sequence[OutboxMessage], *, result_of_cycle: int | None = None) -> Enqueued:
        """Queue ``messages`` (see :meth:`cellctl.store.outbox.OutboxRows.outbox_enqueue`); log and count drops."""
        async with self._lock:
            done = await self.store.outbox_enqueue(
                messages, max_messages=self.max_messages, result_of_cycle=result_of_cycle, in_flight=self.in_flight
            )
            self._gone.update(d.seq for d in done.dropped)
        f = self.figures
        f.pending, f.queued = done.pending, f.queued + len(done.seqs)
        for d in done.dropped:
            is_result = d.kind == RESULT_KIND
            f.dropped += 1
            f.dropped_total += 1
            f.dropped_results += is_result
            f.dropped_results_total += is_result
            log.warning(
                "MQTT outbox full (mqtt.max_messages = %d): dropped message seq %d (%s, %s) before the broker had it%s",
                self.max_messages, d.seq, d.kind, d.topic,
                "; a cycle result is lost to the plant" if is_result else "",
            )  # fmt: skip
        if done.seqs:
            self.wake.set()
        return done

    async def batch(self, limit: int) -> list[OutboxRow]:
        """The oldest pending rows, for the publisher to :meth:`claim` one by one."""
        async with self._lock:
            self._gone.clear()
            return await self.store.outbox_pending(limit=limit)

    async def claim(self, seq: int) -> bool:
        """The publisher is about to send row ``seq``: False when the bound dropped it meanwhile (do not send it)."""
        async with self._lock:
            if seq in self._gone:
                return False
            self.in_flight = seq
            return True

    def sent(self, pending: int) -> None:
        """The broker acknowledged the row in flight and it is deleted; ``pending`` are left."""
        self.in_flight = None
        self.figures.pending = pending
