"""The link's heartbeat: PING a quiet link, drop it when no PONG comes back, reconnect it in the background.

:class:`Heartbeat` starts with the link's first connection, whoever made it (``connect()`` or a first
request), and stops when the link closes; before the first connection nothing runs, so a service
that starts with the controller off does not spin. A link busy with a request waiting for its
answer (GRIP reads nothing while the gripper settles) is left to that request's own deadline; a
PING waiting is no such reason (:meth:`~abb_robot.link.RapidLink.waiting_for`). A motion is
acknowledged at once and the controller answers PING while it runs, so a moving robot is pinged.
"""

from __future__ import annotations

import asyncio
import contextvars
import logging
import time
from typing import Protocol

from abb_robot.settings import AbbRobotSettings
from cellctl.ports import DeviceError

log = logging.getLogger("abb_robot.client")  # the driver's log, as the link's


class HeartbeatLink(Protocol):
    """What the heartbeat needs of :class:`~abb_robot.link.RapidLink`."""

    @property
    def closed(self) -> bool: ...

    def quiet_for(self) -> float | None: ...

    def waiting_for(self) -> str | None: ...

    async def ensure_connected(self, deadline: float) -> None: ...

    async def probe(self, timeout_s: float) -> None: ...


class _Backoff:
    """Growing delays between reconnection attempts (``reconnect_delay_s`` doubling up to ``reconnect_max_delay_s``)."""

    def __init__(self, first_s: float, max_s: float) -> None:
        self.first_s, self.max_s = first_s, max_s
        self.delay_s = first_s
        self.next_at = 0.0

    def due(self) -> bool:
        return time.monotonic() >= self.next_at

    def failed(self) -> float:
        """Schedule the next attempt; returns its delay (s)."""
        delay, self.delay_s = self.delay_s, min(self.delay_s * 2, self.max_s)
        self.next_at = time.monotonic() + delay
        return delay

    def succeeded(self) -> None:
        self.delay_s, self.next_at = self.first_s, 0.0


class Heartbeat:
    """The heartbeat task of one link (see the module docstring); :meth:`start` is idempotent."""

    def __init__(self, link: HeartbeatLink, settings: AbbRobotSettings, name: str) -> None:
        self._link = link
        self._settings = settings
        self._name = name
        self._task: asyncio.Task[None] | None = None

    @property
    def running(self) -> bool:
        """The heartbeat task runs."""
        return self._task is not None and not self._task.done()

    def start(self) -> None:
        """Start the task unless it runs or the link is closed (in a fresh context: nothing of the caller's
        connection set-up leaks into it)."""
        if self.running or self._link.closed:
            return
        self._task = asyncio.create_task(self._run(), name=f"{self._name}-heartbeat", context=contextvars.Context())
        self._task.add_done_callback(self._ended)

    async def stop(self) -> None:
        """Cancel the task and wait for it (1 s at most)."""
        task, self._task = self._task, None
        if task is None or task.done():
            return
        task.cancel()
        try:
            await asyncio.wait_for(task, 1.0)
        except (asyncio.CancelledError, asyncio.TimeoutError, Exception):  # noqa: BLE001 - shutting down
            pass

    def _ended(self, task: asyncio.Task[None]) -> None:
        if not task.cancelled() and task.exception() is not None:
            log.error("%s: heartbeat stopped by an error (it restarts with the next connection): %r",
                      self._name, task.exception())

    async def _run(self) -> None:
        s = self._settings
        backoff = _Backoff(s.reconnect_delay_s, s.reconnect_max_delay_s)
        while not self._link.closed:
            await asyncio.sleep(min(s.heartbeat_period_s, s.reconnect_delay_s) / 2)
            quiet_s = self._link.quiet_for()
            if quiet_s is None:
                if backoff.due():
                    await self._reconnect(backoff)
            elif quiet_s >= s.heartbeat_period_s and self._link.waiting_for() is None:
                await self._link.probe(s.heartbeat_timeout_s)

    async def _reconnect(self, backoff: _Backoff) -> None:
        s = self._settings
        try:
            await self._link.ensure_connected(time.monotonic() + s.connect_timeout_s + s.request_timeout_s)
            backoff.succeeded()
        except DeviceError as exc:
            delay_s = backoff.failed()
            log.info("%s: reconnection failed (%s); next try in %.1f s", self._name, exc.message, delay_s)
