"""The bound never drops what the publisher is sending (dropped means not sent: checked on a real
broker), and the bridge's resync empties the retained topic of an alarm that ended unseen."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

from mosquitto_support import running_broker, subscribed
from mqtt_publisher_support import NAMES, connected, frozen, publisher_config

from cellctl.cell.alarms import AlarmCode, AlarmManager
from cellctl.cell.events import EventHub
from cellctl.cell.packml import PackMLMachine
from cellctl.mqtt.bridge import EventBridge
from cellctl.mqtt.outbox import Outbox
from cellctl.mqtt.publisher import MqttPublisher
from cellctl.mqtt.topics import CellTopics
from cellctl.store import AsyncCellStore
from cellctl.store.outbox import OutboxMessage


async def test_a_message_the_bound_drops_is_one_the_broker_never_gets(tmp_path: Path) -> None:
    store = await AsyncCellStore.open(tmp_path / "cell.db")
    try:
        with running_broker(tmp_path) as broker:
            cfg = publisher_config(broker.port, max_messages=10)
            t = CellTopics(cfg.isa95)
            outbox = Outbox(store, cfg.max_messages)
            with subscribed(broker.port, t.alarm_events) as sub:
                pub = MqttPublisher(cfg, t, outbox)
                pub.start()
                await connected(pub)
                with frozen(broker):  # the first row's PUBACK waits: the publisher holds a batch of ten
                    for n in range(10):
                        await outbox.put([OutboxMessage(t.alarm_events, {"n": n}, "alarm_event")])
                    await asyncio.sleep(0.5)
                    done = await outbox.put([OutboxMessage(t.alarm_events, {"n": 10}, "alarm_event")])
                await asyncio.to_thread(sub.wait_for, "the outbox sent", lambda: any(m.json()["n"] == 10 for m in sub.received))
                await pub.stop()
            got = [m.json()["seq"] for m in sub.received]
    finally:
        await store.close()
    dropped = [d.seq for d in done.dropped]
    assert len(dropped) == 1 and outbox.figures.dropped == 1
    assert dropped[0] not in got, f"seq {dropped} counted as dropped but the broker got it: {got}"
    assert len(got) == 10 and got == sorted(got)


def _alarm_event(a) -> dict:
    return {"uid": a.uid, "code": int(a.code), "message": a.message, "active": a.active, "acknowledged": a.acknowledged}


async def test_an_alarm_that_ended_while_the_bridge_fell_behind_is_emptied(tmp_path: Path) -> None:
    store = await AsyncCellStore.open(tmp_path / "cell.db")
    t = CellTopics(NAMES)
    code = AlarmCode.DISK_SPACE_LOW
    try:
        alarms = AlarmManager(PackMLMachine())
        alarms.install()
        hub = EventHub()
        bridge = EventBridge(Outbox(store, 10_000), t, hub, state_now=lambda: ("STOPPED", "PRODUCTION", "NONE"),
                             alarms=alarms, calibration_now=lambda: {"version": 1})  # fmt: skip
        await bridge.start()
        a = await alarms.raise_alarm(code, source="storage", detail="4.2 GB free")
        hub.publish("alarm", _alarm_event(alarms.get(a.uid)))  # as the orchestrator's pump does
        await asyncio.sleep(0.3)
        alarms.clear(code, source="storage")  # the alarm ends inside a burst the bridge's queue (256) cannot hold
        hub.publish("alarm", _alarm_event(alarms.get(a.uid)))
        alarms.acknowledge(a.uid, by="op")
        hub.publish("alarm", _alarm_event(alarms.get(a.uid)))
        for _ in range(300):
            hub.publish("step", {"cycle_id": 1, "step": "shoot"})
        hub.publish("state", {"state": "STOPPED", "mode": "PRODUCTION", "step": "none"})
        await asyncio.sleep(1.0)
        await bridge.stop()
        held = [r.payload for r in await store.outbox_pending(limit=10_000) if r.topic == t.alarm(code)]
    finally:
        await store.close()
    assert alarms.current() == []  # the truth: no alarm of that code is listed
    assert held and held[-1] == "", f"alarm/{int(code)} is left holding {json.loads(held[-1]) if held else None}"
