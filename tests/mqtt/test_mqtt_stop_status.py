"""A stop says offline on the real broker (mosquitto): after a backlog cut short by the grace, and
through the will when the offline status cannot go out."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

from mosquitto_support import running_broker
from mqtt_publisher_support import connected, frozen, publisher_config, retained_json

from cellctl.mqtt.outbox import Outbox
from cellctl.mqtt.publisher import MqttPublisher
from cellctl.mqtt.topics import CellTopics
from cellctl.store import AsyncCellStore
from cellctl.store.outbox import OutboxMessage


@contextlib.asynccontextmanager
async def _publishing(tmp_path: Path, backlog: int) -> AsyncIterator[tuple[AsyncCellStore, Any, CellTopics, MqttPublisher]]:
    """A publisher connected to a fresh broker with ``backlog`` alarm events still to send."""
    store = await AsyncCellStore.open(tmp_path / "cell.db")
    try:
        with running_broker(tmp_path) as broker:
            cfg = publisher_config(broker.port)
            t = CellTopics(cfg.isa95)
            outbox = Outbox(store, cfg.max_messages)
            for first in range(0, backlog, 1000):
                await outbox.put([OutboxMessage(t.alarm_events, {"n": n}, "alarm_event") for n in range(first, min(first + 1000, backlog))])
            pub = MqttPublisher(cfg, t, outbox)
            pub.start()
            await connected(pub, 5)
            yield store, broker, t, pub
    finally:
        await store.close()


async def test_a_stop_that_cuts_the_backlog_short_still_leaves_status_offline(tmp_path: Path) -> None:
    async with _publishing(tmp_path, 3000) as (store, broker, t, pub):
        with frozen(broker):  # no PUBACK until the grace is over: the backlog is cut short however fast the machine
            stopping = asyncio.create_task(pub.stop(grace_s=0.2))
            while not pub._cut.is_set():  # the grace is over; the broker answers again for the offline status
                await asyncio.sleep(0.01)
        await stopping
        left = (await store.outbox_counts()).pending
        status = await retained_json(broker, t.status)
    assert left > 0, "the backlog went out within the grace; make it longer"
    assert status["online"] is False and status["reason"] == "service stopped", status


async def test_a_stop_whose_offline_status_cannot_go_out_leaves_the_will(tmp_path: Path) -> None:
    async with _publishing(tmp_path, 2000) as (_store, broker, t, pub):
        with frozen(broker):  # no PUBACK, neither for the backlog nor for the offline status: the stop gives up
            await pub.stop(grace_s=0.2)
            assert not pub.connected
        status = await retained_json(broker, t.status)
    assert status["online"] is False and status["reason"] == "connection lost", status  # the will: no clean DISCONNECT
