"""The simulated cell service with MQTT publication on, and cycles run over REST."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
from mosquitto_support import Broker, Subscriber, running_broker, subscribed
from service_test_support import AUTH, sim_config

from cellctl.config import CellConfig
from cellctl.mqtt import CellTopics

FAST_RECONNECT = {"reconnect_min_s": 0.2, "reconnect_max_s": 1.0, "keepalive_s": 5, "publish_timeout_s": 5.0}


def mqtt_config(port: int, **mqtt: Any) -> CellConfig:
    """config/sim.toml (oracle calibration, PLC off) publishing to ``127.0.0.1:port``."""
    fields: dict[str, Any] = {"enabled": True, "host": "127.0.0.1", "port": port, **FAST_RECONNECT, **mqtt}
    return sim_config(plc={"enabled": False}, mqtt=fields)


def topics(config: CellConfig) -> CellTopics:
    return CellTopics(config.mqtt.isa95)


@contextlib.contextmanager
def broker_and_historian(workdir: Path) -> Iterator[tuple[Broker, CellConfig, CellTopics, Subscriber]]:
    """A mosquitto broker of the test's own, the cell's config publishing to it, its topics, and a subscriber to all."""
    with running_broker(workdir) as broker:
        config = mqtt_config(broker.port)
        t = topics(config)
        with subscribed(broker.port, t.everything) as sub:
            yield broker, config, t, sub


async def run_cycle(client: httpx.AsyncClient, n: int) -> dict[str, Any]:
    """One cycle (part ``P-n``) to its end; its REST record."""
    r = await client.post("/cycle?wait=true&timeout_s=60", json={"recipe": "side-window", "part_id": f"P-{n}"},
                          headers={**AUTH, "Idempotency-Key": f"mqtt-{n}"})  # fmt: skip
    assert r.status_code == 200, r.text
    record = r.json()
    assert record["state"] in ("done", "failed"), record
    return dict(record)


async def mqtt_status(client: httpx.AsyncClient) -> dict[str, Any]:
    return dict((await client.get("/status")).json()["mqtt"])


def check_envelopes(bodies: list[dict[str, Any]]) -> None:
    """Every payload: schema version 1, a UTC RFC 3339 time, a unique msg_id, seq strictly increasing."""
    assert all(b["v"] == 1 for b in bodies)
    assert all(b["ts"].endswith("Z") and "T" in b["ts"] for b in bodies)
    ids = [b["msg_id"] for b in bodies]
    assert len(set(ids)) == len(ids) and all(len(i) == 32 for i in ids)
    seqs = [b["seq"] for b in bodies]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs), seqs
