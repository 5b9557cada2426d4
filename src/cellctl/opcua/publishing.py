"""How the server publishes to its subscribers: a fastest publishing interval, and batches of writes that a
subscriber gets whole, in one notification (e.g. one cycle's ``Cycle/LastResult/*``).

asyncua 2.1 keeps the interval a client asks for. At 0 it publishes on the first change queued
(``InternalSubscription._trigger_publish``), so a batch's first write went out alone. The server revises a
requested interval below :data:`MIN_PUBLISHING_INTERVAL_MS` (0 included) up to it, as OPC UA Part 4
(5.13.2) lets it. While a batch is being written, every subscription's publication waits until the batch
is complete, so no notification carries part of a batch.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
from collections.abc import AsyncIterator, Callable
from typing import Any

from asyncua import Server, ua
from asyncua.server.internal_subscription import InternalSubscription

MIN_PUBLISHING_INTERVAL_MS = 10.0
"""The fastest publishing interval the server grants, in ms; a request below it (0 included) is revised to it."""


class Publishing:
    """Installs the interval's minimum and the batch gate on ``server`` (before clients connect)."""

    def __init__(self, server: Server, min_interval_ms: float = MIN_PUBLISHING_INTERVAL_MS) -> None:
        self._min_ms = min_interval_ms
        self._idle = asyncio.Event()
        self._idle.set()
        self._writer: asyncio.Task[Any] | None = None
        service = server.iserver.subscription_service
        create = service.create_subscription

        async def create_subscription(params: ua.CreateSubscriptionParameters, callback: Callable[..., Any],
                                      session_id: ua.NodeId, request_callback: Callable[..., Any] | None = None,
                                      ) -> ua.CreateSubscriptionResult:  # fmt: skip
            params = dataclasses.replace(params, RequestedPublishingInterval=self.revised(params.RequestedPublishingInterval))
            result = await create(params, callback, session_id, request_callback=request_callback)
            sub = service.subscriptions.get(result.SubscriptionId)
            if sub is not None:
                self._gate(sub)
            return result

        service.create_subscription = create_subscription  # type: ignore[method-assign]

    def revised(self, requested_ms: float) -> float:
        """The publishing interval granted for ``requested_ms`` (ms): at least the minimum (NaN: the minimum)."""
        return requested_ms if requested_ms >= self._min_ms else self._min_ms

    @contextlib.asynccontextmanager
    async def batch(self) -> AsyncIterator[None]:
        """Writes made inside reach every subscriber in one notification (no publication meanwhile)."""
        self._idle.clear()
        self._writer = asyncio.current_task()
        try:
            yield
        finally:
            self._writer = None
            self._idle.set()

    def _gate(self, sub: InternalSubscription) -> None:
        publish = sub.publish_results

        async def publish_results(requestdata: Any = None) -> bool:
            while not self._idle.is_set() and asyncio.current_task() is not self._writer:  # never waits for itself
                await self._idle.wait()  # woken, it looks again: another batch may have begun since
            return bool(await publish(requestdata))

        sub.publish_results = publish_results  # type: ignore[method-assign]
