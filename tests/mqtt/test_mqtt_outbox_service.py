"""The outbox in the running service: its bound says what it dropped, and a restart loses nothing pending."""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path

import pytest
from mosquitto_support import Broker, subscribed
from mqtt_service_support import (
    check_envelopes,
    mqtt_config,
    mqtt_status,
    run_cycle,
    topics,
)
from service_test_support import api_client, running_service, to_execute


def _historian(tmp_path: Path) -> Broker:
    """A broker that knows the test's persistent session, then goes down (started again by the test)."""
    broker = Broker(tmp_path)
    broker.start()
    return broker


async def test_a_full_outbox_drops_the_oldest_results_last_and_says_so_after_reconnecting(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    broker = _historian(tmp_path)
    try:
        config = mqtt_config(broker.port, max_messages=10)
        t = topics(config)
        with subscribed(broker.port, t.everything) as sub:
            await asyncio.to_thread(broker.stop)  # the subscriber's session is kept by the broker
            caplog.set_level(logging.WARNING, logger="cellctl.mqtt")
            async with running_service(tmp_path, config) as service, api_client(service) as client:
                await to_execute(client)
                records = [await run_cycle(client, n) for n in range(1, 13)]
                down = await mqtt_status(client)
                await asyncio.to_thread(broker.start)
                await asyncio.to_thread(sub.wait_count, t.dropped, 1, 30.0)
                await asyncio.to_thread(sub.wait_for, "the last result",
                                        lambda: any(m.json()["cycle_id"] == records[-1]["id"] for m in sub.on(t.result)))  # fmt: skip
                up = await mqtt_status(client)
            received = [m.json() for m in sub.on(t.result)]
            report = sub.on(t.dropped)[0].json()
            online = [m.json() for m in sub.on(t.status) if m.json()["online"]][-1]
    finally:
        broker.close()
    # Ten places for twelve results and the retained state, result/last and calibration: the non-results
    # went first (they are queued again after the backlog), then the oldest results.
    ids = [b["cycle_id"] for b in received]
    dropped_results = up["dropped_results"]
    assert dropped_results == 2 and up["dropped"] > dropped_results  # twelve results, ten places
    assert not down["connected"] and down["dropped"] > 0 and down["pending"] == 10
    assert ids == [r["id"] for r in records][dropped_results:], ids  # the newest, in order, once each
    check_envelopes(received)
    assert report["dropped"] == up["dropped_total"] and report["dropped_results"] == dropped_results
    assert report["max_messages"] == 10 and online["dropped_results_total"] == dropped_results
    warned = [r.getMessage() for r in caplog.records if "MQTT outbox full" in r.getMessage()]
    assert len(warned) == up["dropped_total"] and sum("a cycle result is lost" in w for w in warned) == dropped_results


async def test_results_pending_at_a_service_stop_are_published_after_its_restart(tmp_path: Path) -> None:
    broker = _historian(tmp_path)
    try:
        config = mqtt_config(broker.port)
        t = topics(config)
        with subscribed(broker.port, t.result) as sub:
            await asyncio.to_thread(broker.stop)
            async with running_service(tmp_path, config) as service, api_client(service) as client:
                await to_execute(client)
                records = [await run_cycle(client, n) for n in (1, 2, 3)]
                assert (await mqtt_status(client))["pending"] >= 3
            await asyncio.to_thread(broker.start)
            async with running_service(tmp_path, config) as service, api_client(service) as client:
                got = await asyncio.to_thread(sub.wait_count, t.result, 3, 30.0)
                await asyncio.sleep(0.5)  # a duplicate would arrive now
            bodies = [m.json() for m in sub.on(t.result)]
            assert [b["cycle_id"] for b in bodies] == [r["id"] for r in records]
            check_envelopes(bodies)
            assert len(got) == 3
    finally:
        broker.close()
