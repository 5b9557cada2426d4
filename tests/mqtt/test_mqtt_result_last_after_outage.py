"""The retained ``result/last`` after a broker outage longer than the outbox's bound: the newest finished cycle.

The bound (``max_messages`` = 10, twelve cycles) drops every ``result/last`` of the outage, so the
value must come from the re-queue after the backlog. Peers: Debian's mosquitto with persistence,
paho subscribers (a historian on everything, and a fresh reader of the retained value after the
outage) and the REST records of the cycles.
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import httpx
from mosquitto_support import Broker, Subscriber, subscribed
from mqtt_service_support import check_envelopes, mqtt_config, mqtt_status, run_cycle, topics
from service_test_support import api_client, running_service, to_execute

from cellctl.mqtt import CellTopics

ENVELOPE = ("v", "ts", "msg_id", "seq")
OUTAGE_CYCLES = 12  # more than max_messages = 10 holds
WAIT_S = 30.0


async def _newest_finished(client: httpx.AsyncClient) -> dict[str, Any]:
    """The REST record of the newest cycle (every cycle here has finished)."""
    brief = (await client.get("/cycles", params={"limit": 1})).json()[0]
    record = (await client.get(f"/cycles/{brief['id']}")).json()
    assert record["state"] in ("done", "failed"), record
    return dict(record)


def _retained_last(port: int, t: CellTopics, reader: str) -> dict[str, Any]:
    """What the broker holds on ``result/last``, read by a new client that subscribes after the outage."""
    with subscribed(port, t.result_last, reader) as late:
        late.wait_count(t.result_last, 1, 10.0)
        held = [m for m in late.on(t.result_last) if m.retain]
    assert len(held) == 1 and held[0].payload, held
    return held[0].json()


async def _outage(client: httpx.AsyncClient, broker: Broker, first: int) -> list[dict[str, Any]]:
    """Stop the broker, run more cycles than the bound holds, start it again; the cycles' REST records."""
    await asyncio.to_thread(broker.stop)  # the historian's session and the retained topics are kept on disk
    records = [await run_cycle(client, n) for n in range(first, first + OUTAGE_CYCLES)]
    await asyncio.to_thread(broker.start)
    return records


async def _check_last(sub: Subscriber, broker: Broker, t: CellTopics, newest: dict[str, Any], reader: str) -> None:
    """``result/last`` reached the historian after the backlog, and the broker retains it: the newest cycle's result."""
    nid = newest["id"]
    await asyncio.to_thread(sub.wait_for, "the newest cycle's result", lambda: any(m.json()["cycle_id"] == nid for m in sub.on(t.result)))
    await asyncio.to_thread(sub.wait_for, f"result/last of the newest cycle {nid} after the outage",
                            lambda: any(m.json()["cycle_id"] == nid for m in sub.on(t.result_last)), WAIT_S)  # fmt: skip
    result = next(m.json() for m in sub.on(t.result) if m.json()["cycle_id"] == nid)
    last = [m.json() for m in sub.on(t.result_last)][-1]
    held = await asyncio.to_thread(_retained_last, broker.port, t, reader)
    for body in (last, held):  # the same payload as the cycle's `result`, but the envelope
        assert {k: v for k, v in body.items() if k not in ENVELOPE} == {k: v for k, v in result.items() if k not in ENVELOPE}
        assert body["cycle_id"] == nid and body["part_id"] == newest["part_id"] and body["state"] == newest["state"]
        assert body["ok"] == newest["result"]["ok"] and body["error_code"] == newest["result"]["error_code"]
        assert body["measured_deviation"] == newest["measured_deviation"]
        assert body["seq"] > result["seq"]  # after the backlog: no older value can follow it
    assert held["msg_id"] == last["msg_id"]  # what the broker keeps is the last one the historian got


def _results_once_in_order(sub: Subscriber, t: CellTopics, expected: list[int]) -> None:
    bodies = [m.json() for m in sub.on(t.result)]
    assert [b["cycle_id"] for b in bodies] == expected
    check_envelopes(bodies)


async def test_result_last_holds_the_newest_cycle_after_a_first_outage_and_a_later_one(tmp_path: Path) -> None:
    broker = Broker(tmp_path)
    broker.start()
    try:
        config = mqtt_config(broker.port, max_messages=10)
        t = topics(config)
        with subscribed(broker.port, t.everything) as sub:
            async with running_service(tmp_path, config) as service, api_client(service) as client:
                await to_execute(client)
                # A first outage: the broker never held result/last.
                first = await _outage(client, broker, 1)
                newest = await _newest_finished(client)
                assert newest["id"] == first[-1]["id"]
                await _check_last(sub, broker, t, newest, "late-reader-1")
                lost = (await mqtt_status(client))["dropped_results"]
                assert 0 < lost < OUTAGE_CYCLES  # the bound dropped results: the outage outlasted it
                expected = [r["id"] for r in first][lost:]  # the newest, once each, in order
                _results_once_in_order(sub, t, expected)
                # A cycle with the broker up sets result/last; a second outage must not leave it there.
                before = await run_cycle(client, 100)
                await asyncio.to_thread(sub.wait_for, "result/last of the cycle before the second outage",
                                        lambda: any(m.json()["cycle_id"] == before["id"] for m in sub.on(t.result_last)))  # fmt: skip
                second = await _outage(client, broker, 200)
                newest = await _newest_finished(client)
                assert newest["id"] == second[-1]["id"]
                await _check_last(sub, broker, t, newest, "late-reader-2")
                lost = (await mqtt_status(client))["dropped_results"] - lost
                assert 0 < lost < OUTAGE_CYCLES
                expected += [before["id"], *[r["id"] for r in second][lost:]]
                _results_once_in_order(sub, t, expected)
                await asyncio.sleep(0.5)  # a duplicate, or an older result/last, would arrive now
                _results_once_in_order(sub, t, expected)
                assert [m.json() for m in sub.on(t.result_last)][-1]["cycle_id"] == newest["id"]
    finally:
        broker.close()
