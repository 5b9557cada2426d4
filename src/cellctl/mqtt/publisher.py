"""The publisher: one asyncio task that keeps a connection to the broker and drains the outbox in order.

Each connection attempt makes a new :class:`aiomqtt.Client`: a client that is reused keeps a
publish that failed offline in paho's memory and sends it again after its reconnection, which
duplicates the row the outbox sends again anyway. A connection has a retained ``status`` will
({"online": false}); once connected it publishes the retained ``status`` {"online": true}, then
an ``outbox/dropped`` report if the bound dropped messages while it was away, and sends the rows
oldest first, deleting each only after :meth:`aiomqtt.Client.publish` returned (the broker's
PUBACK). Once the backlog is out it lets the bridge queue the current state, alarms,
calibration and result/last again (a broker without persistence lost them; after the backlog, they cannot
push a result out of a full outbox). A second task iterates the
client's messages: it ends when the connection is lost, even while there is nothing to send.
After a failure it waits ``reconnect_min_s``, doubled each time up to ``reconnect_max_s``, with
jitter, and tries again. :meth:`MqttPublisher.stop` sends what it can within its grace, then (the
backlog cut short if need be) publishes {"online": false} and disconnects; a broker that is down
does not hold it up. A connection never ends with a clean DISCONNECT (which makes the broker
discard the will) unless that status went out: otherwise it is dropped, and the will speaks.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
import socket
from collections.abc import Awaitable, Callable
from datetime import UTC, datetime
from typing import Any

import aiomqtt

from cellctl.config.mqtt import MqttConfig
from cellctl.mqtt import payloads
from cellctl.mqtt.outbox import Outbox
from cellctl.mqtt.topics import CellTopics

log = logging.getLogger(__name__)

BATCH = 100  # rows read from the store at a time
CANCEL_WAIT_S = 1.25  # at a stop, after the grace: how long the connection may take to say offline and close
OFFLINE_TIMEOUT_S = 1.0  # at a stop, the longest wait for the PUBACK of {"online": false}


def backoff_s(attempt: int, min_s: float, max_s: float, rng: random.Random | None = None) -> float:
    """The wait before attempt ``attempt`` + 1 (0-based): min_s doubled per failure, capped at max_s, 50-100 % of it."""
    ceiling = min(max_s, min_s * 2.0 ** min(attempt, 30))
    return (rng or random).uniform(ceiling / 2.0, ceiling)


class MqttPublisher:
    """Keeps the connection and sends the outbox (see the module docstring)."""

    def __init__(
        self,
        config: MqttConfig,
        topics: CellTopics,
        outbox: Outbox,
        *,
        password: str | None = None,
        tls: aiomqtt.TLSParameters | None = None,
        caught_up: Callable[[], Awaitable[None]] | None = None,
    ) -> None:
        self.config = config
        self.topics = topics
        self.outbox = outbox
        self._password = password
        self._tls = tls
        self._caught_up = caught_up
        self._task: asyncio.Task[None] | None = None
        self._stopping = asyncio.Event()
        self._cut = asyncio.Event()  # the stop's grace is over: leave the backlog, say offline, disconnect
        self.connected = False
        self.connects = 0
        self.published = 0
        self.last_error: str | None = None
        self.connected_since: datetime | None = None

    # -- lifecycle ------------------------------------------------------------------------------

    def start(self) -> None:
        if self._task is None:
            self._task = asyncio.create_task(self._run(), name="mqtt-publisher")

    async def stop(self, grace_s: float = 3.0) -> None:
        """Send what is pending for up to ``grace_s``, publish {"online": false}, disconnect; then give up.

        Returns within about ``grace_s`` + 2 s whatever the broker does; unsent rows stay in the outbox.
        """
        self._stopping.set()
        self.outbox.wake.set()
        task, self._task = self._task, None
        if task is None:
            return
        done, _ = await asyncio.wait({task}, timeout=grace_s)
        if not done:  # the backlog is cut short: the session says offline (or drops the connection) and ends
            self._cut.set()
            done, _ = await asyncio.wait({task}, timeout=CANCEL_WAIT_S)
        for _ in range(2):  # a second cancel ends a disconnect the broker never answers
            if done:
                break
            task.cancel()
            done, _ = await asyncio.wait({task}, timeout=CANCEL_WAIT_S / 2)
        if not done:
            log.warning("MQTT publisher did not end within %.0f s of the stop; left behind", grace_s + 2 * CANCEL_WAIT_S)
        elif not task.cancelled() and task.exception() is not None:
            log.warning("MQTT publisher ended with %r", task.exception())
        self.connected = False

    def status(self) -> dict[str, Any]:
        """The connection and the outbox for /status."""
        f = self.outbox.figures
        return {
            "broker": f"{self.config.host}:{self.config.port}", "client_id": self.config.effective_client_id,
            "topic_prefix": self.topics.prefix, "connected": self.connected, "connects": self.connects,
            "connected_since_utc": None if self.connected_since is None else self.connected_since.isoformat(),
            "last_error": self.last_error, "published": self.published, "pending": f.pending,
            "queued": f.queued, "dropped": f.dropped, "dropped_results": f.dropped_results,
            "dropped_total": f.dropped_total, "dropped_results_total": f.dropped_results_total,
            "max_messages": self.outbox.max_messages,
        }  # fmt: skip

    # -- the connection loop --------------------------------------------------------------------

    async def _run(self) -> None:
        attempt = 0
        while not self._stopping.is_set():
            try:
                if await self._session():
                    return  # stopped cleanly
                attempt = 0  # it was connected: start the back-off afresh
            except aiomqtt.MqttError as err:
                self._failed(err)
            except Exception as err:  # a fault here must not end publication; logged with its trace
                log.exception("MQTT publisher: unexpected fault")
                self._failed(err)
            delay = backoff_s(attempt, self.config.reconnect_min_s, self.config.reconnect_max_s)
            attempt += 1
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(self._stopping.wait(), delay)

    def _failed(self, err: BaseException) -> None:
        text = f"{type(err).__name__}: {err}"
        if self.connected or text != self.last_error:  # once per kind of failure, not at every retry
            log.warning("MQTT broker %s:%d: %s; retrying with back-off", self.config.host, self.config.port, text)
        self.last_error = text
        self.connected = False

    async def _direct(
        self, client: aiomqtt.Client, topic: str, body: dict[str, Any], *, retain: bool, seq: int | None = None,
        timeout_s: float | None = None,
    ) -> None:
        """Publish a message that has no outbox row (status, drop report), with ``seq`` or a fresh one."""
        seq = seq if seq is not None else await self.outbox.store.outbox_next_seq()
        await client.publish(topic, payloads.encode(body, seq=seq), qos=self.config.qos, retain=retain,
                             timeout=timeout_s or self.config.publish_timeout_s)  # fmt: skip
        self.published += 1

    def _client(self, will: bytes) -> aiomqtt.Client:
        c = self.config
        return aiomqtt.Client(
            c.host, c.port, identifier=c.effective_client_id, username=c.username, password=self._password,
            will=aiomqtt.Will(self.topics.status, will, qos=c.qos, retain=True), clean_session=True,
            keepalive=c.keepalive_s, timeout=c.publish_timeout_s, tls_params=self._tls,
            logger=logging.getLogger("cellctl.mqtt.paho"),
        )  # fmt: skip

    async def _session(self) -> bool:
        """One connection: returns True when it ended because the service stops, raises when it was lost."""
        cid = self.config.effective_client_id
        online_seq = await self.outbox.store.outbox_next_seq()  # before the will's: on `status` seq keeps rising
        will_seq = await self.outbox.store.outbox_next_seq()
        will = payloads.encode(payloads.status(online=False, client_id=cid, reason="connection lost"), seq=will_seq)
        async with self._client(will) as client:
            said_offline = False
            try:
                self.connected, self.connects, self.last_error = True, self.connects + 1, None
                self.connected_since = datetime.now(UTC)
                log.info("MQTT connected to %s:%d as %s (topics %s/...)", self.config.host, self.config.port, cid, self.topics.prefix)
                await self._hello(client, cid, online_seq)
                await self._serve(client)
                await self._direct(client, self.topics.status, payloads.status(
                    online=False, client_id=cid, reason="service stopped"), retain=True,
                    timeout_s=min(OFFLINE_TIMEOUT_S, self.config.publish_timeout_s))  # fmt: skip
                said_offline = True
                self.connected = False
                return True
            finally:
                if not said_offline:  # no clean DISCONNECT: the broker must publish the will
                    drop_connection(client)

    async def _hello(self, client: aiomqtt.Client, cid: str, online_seq: int) -> None:
        """The retained {"online": true}, then the drop report if the bound dropped messages while away."""
        counts = await self.outbox.store.outbox_counts()
        await self._direct(client, self.topics.status, payloads.status(
            online=True, client_id=cid, reason="connected", pending=counts.pending,
            dropped_total=counts.dropped_total, dropped_results_total=counts.dropped_results,
        ), retain=True, seq=online_seq)  # fmt: skip
        if counts.unreported_dropped:
            await self._direct(client, self.topics.dropped, payloads.dropped(
                dropped=counts.unreported_dropped, dropped_results=counts.unreported_dropped_results,
                dropped_total=counts.dropped_total, max_messages=self.outbox.max_messages,
            ), retain=False)  # fmt: skip
            await self.outbox.store.outbox_drops_reported(counts.unreported_dropped, counts.unreported_dropped_results)

    async def _serve(self, client: aiomqtt.Client) -> None:
        """Watch the connection and drain the outbox; returns when the service stops (the backlog is out,
        or the stop's grace is over), raises when the connection was lost."""
        watcher = asyncio.create_task(self._watch(client))
        drainer = asyncio.create_task(self._drain(client))
        cut = asyncio.create_task(self._cut.wait())
        try:
            done, _ = await asyncio.wait({watcher, drainer, cut}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for t in (watcher, drainer, cut):
                t.cancel()
                with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
                    await t
        if cut in done or (drainer in done and drainer.exception() is None):
            return
        for t in done:
            if t.exception() is not None:
                raise t.exception()  # type: ignore[misc]
        raise aiomqtt.MqttError("the connection ended")

    async def _watch(self, client: aiomqtt.Client) -> None:
        """Ends (MqttError) when the connection is lost; nothing is subscribed, so nothing arrives."""
        async for _ in client.messages:
            pass

    async def _drain(self, client: aiomqtt.Client) -> None:
        """Send the rows in order until the service stops and nothing is left (returns) or a publish fails (raises)."""
        outbox = self.outbox
        caught_up = False
        while True:
            outbox.wake.clear()
            rows = await outbox.batch(BATCH)
            if not rows:
                if not caught_up and self._caught_up is not None:  # the backlog is out: the current values after it
                    caught_up = True
                    try:
                        await self._caught_up()
                    except Exception:  # publication goes on without them; logged with its trace
                        log.exception("MQTT publisher: the current values could not be queued after the backlog")
                    continue
                if self._stopping.is_set():
                    return
                await outbox.wake.wait()
                continue
            for row in rows:
                if not await outbox.claim(row.seq):
                    continue  # the bound dropped it after the batch was read: it stays unsent
                await client.publish(row.topic, row.payload.encode(), qos=row.qos, retain=row.retain,
                                     timeout=self.config.publish_timeout_s)  # fmt: skip
                self.published += 1
                outbox.sent(await outbox.store.outbox_delete(row.seq))


def drop_connection(client: aiomqtt.Client) -> None:
    """End the connection without a DISCONNECT packet, so that the broker publishes the will.

    aiomqtt has no call for it: its ``__aexit__`` always disconnects cleanly unless the connection
    is already gone. Shutting the socket down sends nothing more to the broker (it sees the
    connection close); marking aiomqtt's connection ended makes ``__aexit__`` skip its DISCONNECT.
    """
    paho = getattr(client, "_client", None)
    sock = paho.socket() if paho is not None else None
    if sock is not None:
        with contextlib.suppress(OSError):
            sock.shutdown(socket.SHUT_RDWR)
    ended = getattr(client, "_disconnected", None)
    if isinstance(ended, asyncio.Future) and not ended.done():
        ended.set_result(None)
