"""The outbox in the store: order, one sequence, the bound (results last), retained topics replaced,
and the results' high-water mark that makes the catch-up after a restart exact."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cellctl.cell.events import EventHub
from cellctl.config.mqtt import Isa95Names
from cellctl.domain import Alarm
from cellctl.mqtt.bridge import EventBridge
from cellctl.mqtt.outbox import Outbox
from cellctl.mqtt.topics import CellTopics
from cellctl.store import AsyncCellStore, CellStore, CycleRequest
from cellctl.store.outbox import OutboxMessage


def _msg(topic: str, kind: str, *, retain: bool = False, n: int = 0) -> OutboxMessage:
    return OutboxMessage(topic, {"n": n}, kind, retain=retain)


def test_rows_come_back_in_order_with_their_seq_in_the_payload(tmp_path: Path) -> None:
    with CellStore.open(tmp_path / "cell.db") as store:
        done = store.outbox_enqueue([_msg("a/result", "result", n=1), _msg("a/state", "state", retain=True)], max_messages=10)
        assert done.seqs == (1, 2) and done.pending == 2 and done.dropped == ()
        assert store.outbox_next_seq() == 3  # a message without a row takes the next one
        store.outbox_enqueue([_msg("a/result", "result", n=2)], max_messages=10)
        rows = store.outbox_pending()
        assert [(r.seq, r.topic, r.retain) for r in rows] == [(1, "a/result", False), (2, "a/state", True), (4, "a/result", False)]
        assert [json.loads(r.payload)["seq"] for r in rows] == [1, 2, 4]
        assert store.outbox_delete(1) == 2
    with CellStore.open(tmp_path / "cell.db") as store:  # durable, and the sequence never goes back
        assert [r.seq for r in store.outbox_pending()] == [2, 4]
        store.outbox_delete(2)
        store.outbox_delete(4)
        assert store.outbox_enqueue([_msg("a/result", "result")], max_messages=10).seqs == (5,)


def test_a_retained_topic_keeps_one_pending_value_and_an_empty_message_clears(tmp_path: Path) -> None:
    with CellStore.open(tmp_path / "cell.db") as store:
        for n in range(5):
            store.outbox_enqueue([_msg("a/state", "state", retain=True, n=n)], max_messages=10)
        store.outbox_enqueue([_msg("a/alarm/1701", "alarm", retain=True)], max_messages=10)
        rows = store.outbox_pending()
        assert [(r.topic, json.loads(r.payload)["n"]) for r in rows] == [("a/state", 4), ("a/alarm/1701", 0)]
        assert store.outbox_counts().dropped_total == 0  # superseded, not dropped
        assert store.outbox_retained_topics() == ["a/alarm/1701", "a/state"]
        store.outbox_enqueue([OutboxMessage("a/alarm/1701", None, "alarm", retain=True)], max_messages=10)
        assert store.outbox_pending()[-1].payload == "" and store.outbox_retained_topics() == ["a/state"]


def test_the_bound_drops_the_oldest_non_result_first_and_a_result_only_for_a_newer_result(tmp_path: Path) -> None:
    with CellStore.open(tmp_path / "cell.db") as store:
        store.outbox_enqueue([_msg("a/alarm/events", "alarm_event")], max_messages=10)
        for n in range(8):
            store.outbox_enqueue([_msg("a/result", "result", n=n)], max_messages=10)
        store.outbox_enqueue([_msg("a/state", "state", retain=True)], max_messages=10)
        full = store.outbox_enqueue([_msg("a/result", "result", n=8)], max_messages=10)
        assert [(d.seq, d.kind) for d in full.dropped] == [(1, "alarm_event")] and full.pending == 10
        more = store.outbox_enqueue([_msg("a/result", "result", n=9)], max_messages=10)
        assert [d.kind for d in more.dropped] == ["state"]
        last = store.outbox_enqueue([_msg("a/result", "result", n=10)], max_messages=10)
        assert [(d.seq, d.kind) for d in last.dropped] == [(2, "result")]  # only results left: the oldest goes
        assert [json.loads(r.payload)["n"] for r in store.outbox_pending()] == list(range(1, 11))
        state = store.outbox_enqueue([_msg("a/state", "state", retain=True)], max_messages=10)
        assert state.seqs == () and [(d.kind, d.seq) for d in state.dropped] == [("state", 14)]  # never pushes a result out
        assert [json.loads(r.payload)["n"] for r in store.outbox_pending()] == list(range(1, 11))
        c = store.outbox_counts()
        assert (c.dropped_total, c.dropped_results, c.unreported_dropped, c.unreported_dropped_results) == (4, 1, 4, 1)
        store.outbox_drops_reported(4, 1)
        assert store.outbox_counts().unreported_dropped == 0 and store.outbox_counts().dropped_total == 4
        with pytest.raises(ValueError, match="max_messages"):
            store.outbox_enqueue([_msg("a", "x"), _msg("b", "x")], max_messages=2)


def _finish(store: CellStore, n: int, *, fail: bool = False) -> int:
    cid = store.submit_cycle(CycleRequest(recipe="side-window", part_id=f"P-{n}"), scope="test", key=f"k{n}", actor="t").cycle.id
    store.start_cycle(cid)
    if fail:
        store.fail_cycle(cid, error="stopped: test", result={"error_code": 1308, "cycle_time_s": 1.0})
    else:
        store.complete_cycle(cid, result={"ok": True, "error_code": 0, "cycle_time_s": 2.0, "correction_mm": [1, 2, 3]})
    return cid


def test_the_high_water_mark_starts_at_the_newest_cycle_and_queues_a_result_once(tmp_path: Path) -> None:
    with CellStore.open(tmp_path / "cell.db") as store:
        old = _finish(store, 1)
        assert store.outbox_start_results() == old  # history before publication is not published
        assert store.outbox_start_results() == old
        assert store.outbox_result_backlog() == []
        new = _finish(store, 2)
        running = store.submit_cycle(CycleRequest(recipe="side-window", part_id="P-3"), scope="test", key="k3", actor="t")
        assert store.outbox_result_backlog() == [new]  # up to the first that has not finished
        first = store.outbox_enqueue([_msg("a/result", "result")], max_messages=10, result_of_cycle=new)
        again = store.outbox_enqueue([_msg("a/result", "result")], max_messages=10, result_of_cycle=new)
        assert first.seqs and not again.seqs and store.outbox_counts().result_hwm == new
        assert store.outbox_result_backlog() == [] and running.created


class _NoAlarms:
    def current(self) -> list[Alarm]:
        return []

    def get(self, uid: str) -> Alarm:
        raise KeyError(uid)


def _bridge(store: AsyncCellStore) -> EventBridge:
    topics = CellTopics(Isa95Names(enterprise="acme", site="s1", area="body", line="l2", cell="c7"))
    return EventBridge(
        Outbox(store, 100), topics, EventHub(), state_now=lambda: ("EXECUTE", "PRODUCTION", "NONE"), alarms=_NoAlarms(),
        calibration_now=lambda: {"version": 3, "parts": {"camera": "cam-1"}},
    )  # fmt: skip


async def test_results_finished_while_no_bridge_ran_are_queued_at_start_in_order_once(tmp_path: Path) -> None:
    """A restart between a cycle's end and its queueing: the next start queues it, and only once."""
    store = await AsyncCellStore.open(tmp_path / "cell.db")
    sync = store._store
    try:
        first = _bridge(store)
        await first.start()  # publication begins: the mark at the newest cycle (none)
        await first.stop()
        ids = [await store.call(_finish, sync, n, fail=n == 2) for n in (1, 2, 3)]
        for _ in range(2):  # a second start finds nothing more to queue
            bridge = _bridge(store)
            await bridge.start()
            await bridge.stop()
        rows = await store.outbox_pending()
        results = [json.loads(r.payload) for r in rows if r.topic == "acme/s1/body/l2/c7/cellctl/result"]
        assert [(b["cycle_id"], b["ok"], b["state"]) for b in results] == [(ids[0], True, "done"), (ids[1], False, "failed"), (ids[2], True, "done")]
        assert results[1]["error_code"] == 1308 and results[1]["reason"] == "stopped: test"
        last = [json.loads(r.payload) for r in rows if r.topic.endswith("/result/last")]
        assert [b["cycle_id"] for b in last] == [ids[2]]  # retained: one pending value
        cal = [json.loads(r.payload) for r in rows if r.topic.endswith("/calibration")]
        assert cal and cal[-1]["version"] == "3" and cal[-1]["parts"] == {"camera": "cam-1"}
    finally:
        await store.close()
