"""A publisher over a real store and a real mosquitto, without the service around it."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
from collections.abc import Iterator
from typing import Any

from mosquitto_support import Broker, subscribed

from cellctl.config.mqtt import Isa95Names, MqttConfig
from cellctl.mqtt.publisher import MqttPublisher

NAMES = Isa95Names(enterprise="acme", site="s1", area="body", line="l4", cell="g1")


def publisher_config(port: int, **fields: Any) -> MqttConfig:
    base: dict[str, Any] = {"enabled": True, "host": "127.0.0.1", "port": port, "reconnect_min_s": 0.2,
                            "reconnect_max_s": 1.0, "keepalive_s": 5, "publish_timeout_s": 5.0, "isa95": NAMES}  # fmt: skip
    return MqttConfig(**{**base, **fields})


@contextlib.contextmanager
def frozen(broker: Broker) -> Iterator[None]:
    """The broker stopped (SIGSTOP): it reads and answers nothing until the block ends."""
    assert broker.proc is not None
    os.kill(broker.proc.pid, signal.SIGSTOP)
    try:
        yield
    finally:
        os.kill(broker.proc.pid, signal.SIGCONT)


async def connected(pub: MqttPublisher, published: int = 0) -> None:
    """Until the publisher is connected and the broker acknowledged more than ``published`` messages."""
    for _ in range(200):
        if pub.connected and pub.published > published:
            return
        await asyncio.sleep(0.05)
    raise AssertionError(f"the publisher did not connect: {pub.status()}")


async def retained_json(broker: Broker, topic: str) -> dict[str, Any]:
    """The value the broker retains on ``topic``, as a new subscriber gets it."""
    with subscribed(broker.port, topic, "late-reader") as late:
        await asyncio.to_thread(late.wait_count, topic, 1)
        assert late.received[-1].retain
        return late.received[-1].json()
