"""Store: part traceability queries (by car body, by glass, by time window, paged) and a cycle's actions."""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest

from cellctl.domain import Alarm, AlarmCode, CycleStep, FaultClass, Severity
from cellctl.store import CellStore, CycleRequest, CycleState
from cellctl.store.parts import PartPage

T0 = datetime(2026, 3, 1, 6, 0, tzinfo=timezone.utc)


class Clock:
    """A clock the test sets (each store call stamps rows with ``now``)."""

    def __init__(self) -> None:
        self.now = T0

    def __call__(self) -> datetime:
        return self.now


@pytest.fixture
def clock() -> Clock:
    return Clock()


@pytest.fixture
def store(tmp_path: Path, clock: Clock) -> Iterator[CellStore]:
    s = CellStore.open(tmp_path / "cell.db", clock=clock)
    yield s
    s.close()


PNG = b"\x89PNG\r\n\x1a\n not really an image"


def install(store: CellStore, clock: Clock, part: str, car: str | None, *, minute: int, ok: bool = True) -> int:
    """One cycle, ending at T0 + ``minute`` min: a shoot step with figures and an image with its digest."""
    clock.now = T0 + timedelta(minutes=minute) - timedelta(seconds=30)
    cid = store.submit_cycle(CycleRequest("side-window", part, car, "plc"), scope="plc", key=f"{part}@{minute}", actor="plc").cycle.id
    store.start_cycle(cid)
    store.begin_step(cid, CycleStep.SHOOT)
    store.add_image(cid, CycleStep.SHOOT, name="shot1", uri=f"cycle-{cid}-shot1.png",
                    sha256=hashlib.sha256(PNG).hexdigest(), size_bytes=len(PNG))  # fmt: skip
    store.finish_step(cid, CycleStep.SHOOT, ok=True, figures={"corner_px": [812.5, 403.25]})
    clock.now = T0 + timedelta(minutes=minute)
    if ok:
        store.complete_cycle(cid, result={"ok": True, "error_code": 0, "calibration_version": "7"})
    else:
        store.fail_cycle(cid, error="corner not found", result={"error_code": 1302})
    return cid


def ids(page: PartPage) -> list[int]:
    return [i.record.id for i in page.installs]


def end(minute: int) -> datetime:
    """When :func:`install` with this ``minute`` ended the cycle."""
    return T0 + timedelta(minutes=minute)


def test_installs_by_car_by_glass_and_by_window_with_paging(store: CellStore, clock: Clock) -> None:
    a1 = install(store, clock, "G-1", "CAR-A", minute=1)
    a2 = install(store, clock, "G-2", "CAR-A", minute=2, ok=False)
    b1 = install(store, clock, "G-3", "CAR-B", minute=3)
    again = install(store, clock, "G-1", "CAR-B", minute=4)  # glass G-1 taken out and installed again
    clock.now = T0 + timedelta(minutes=5)
    queued = store.submit_cycle(CycleRequest("side-window", "G-4", "CAR-A"), scope="rest", key="q", actor="op").cycle.id

    assert ids(store.part_installs(car_id="CAR-A")) == [a1, a2, queued]
    assert ids(store.part_installs(part_id="G-1")) == [a1, again]
    assert ids(store.part_installs(car_id="CAR-B", part_id="G-1")) == [again]
    assert ids(store.part_installs(car_id="nope")) == []
    # The window is on when the install ended: since inclusive, until exclusive; a queued cycle has not ended.
    assert ids(store.part_installs(since=end(2), until=end(4))) == [a2, b1]
    assert ids(store.part_installs(since=end(1))) == [a1, a2, b1, again]
    assert ids(store.part_installs(until=end(2))) == [a1]
    # Back-to-back windows list every ended install once, whatever the offset the times are given in.
    cet = timezone(timedelta(hours=1))
    halves = [store.part_installs(since=end(0), until=end(3).astimezone(cet)), store.part_installs(since=end(3).astimezone(cet))]
    assert ids(halves[0]) + ids(halves[1]) == [a1, a2, b1, again]

    # Paging by cycle id: every install once, the last page says so.
    seen, after = [], None
    while True:
        page = store.part_installs(limit=2, after_id=after)
        seen += ids(page)
        if page.next_after is None:
            break
        assert len(page.installs) == 2 and page.next_after == seen[-1]
        after = page.next_after
    assert seen == [a1, a2, b1, again, queued]
    assert store.part_installs(limit=5).next_after is None  # exactly full: no empty extra page

    # A page holds the whole record: steps with figures, images with their digest.
    rec = store.part_installs(part_id="G-2").installs[0].record
    assert rec.state is CycleState.FAILED and rec.error == "corner not found"
    assert rec.steps[0].figures == {"corner_px": [812.5, 403.25]}
    image = rec.images[0]
    assert (image.sha256, image.size_bytes) == (hashlib.sha256(PNG).hexdigest(), len(PNG))
    assert store.cycle(a2).images == rec.images


def test_the_actions_of_a_cycle_are_its_audit_entries_and_its_alarms(store: CellStore, clock: Clock) -> None:
    first = install(store, clock, "G-1", "CAR-A", minute=1)
    other = install(store, clock, "G-2", "CAR-A", minute=2)
    store.append_audit(actor="anna", source="rest:10.0.0.5", action="command:hold", state_before="EXECUTE",
                       state_after="HOLDING", cycle_id=first)  # fmt: skip
    store.append_audit(actor="anna", source="rest:10.0.0.5", action="command:unhold", cycle_id=other)
    store.append_audit(actor="anna", source="rest:10.0.0.5", action="mode:maintenance")  # no cycle
    raised = T0 + timedelta(seconds=20)
    store.save_alarm(Alarm(
        uid="a-1", code=AlarmCode.CORNER_NOT_FOUND, value=0, message="corner not found", category=FaultClass.MEASUREMENT_NOK,
        severity=Severity.ERROR, source="vision", raised_at=raised, active=False, condition=False,
        ack_at=raised + timedelta(seconds=40), ack_by="anna", cleared_at=raised + timedelta(seconds=5), cycle_id=first,
    ))  # fmt: skip

    actions = store.cycle_actions(first)
    assert [(a.actor, a.action, a.cycle_id) for a in actions.audit] == [("anna", "command:hold", first)]
    assert [(a.uid, a.ack_by, a.ack_at, a.cleared_at) for a in actions.alarms] == [
        ("a-1", "anna", raised + timedelta(seconds=40), raised + timedelta(seconds=5))
    ]
    page = store.part_installs(car_id="CAR-A")
    assert [(i.record.id, [a.action for a in i.actions.audit], len(i.actions.alarms)) for i in page.installs] == [
        (first, ["command:hold"], 1), (other, ["command:unhold"], 0),
    ]  # fmt: skip
    assert store.cycle_actions(999).audit == () and store.cycle_actions(999).alarms == ()
    assert store.verify_audit_chain() == 3  # the audit refactor kept the chain's hashing as it was


def test_the_queries_use_the_traceability_indexes(store: CellStore) -> None:
    def plan(sql: str) -> str:
        return " ".join(r[3] for r in store._conn.execute(f"EXPLAIN QUERY PLAN {sql}", (1,)))

    assert "cycles_by_car" in plan("SELECT id FROM cycles WHERE car_id = ? ORDER BY id")
    assert "cycles_by_part" in plan("SELECT id FROM cycles WHERE part_id = ? ORDER BY id")
    assert "audit_log_by_cycle" in plan("SELECT seq FROM audit_log WHERE cycle_id = ? ORDER BY seq")
    assert "alarms_by_cycle" in plan("SELECT uid FROM alarms WHERE cycle_id = ?")


def test_bad_arguments_and_digests_are_refused_naming_them(store: CellStore, clock: Clock) -> None:
    cid = install(store, clock, "G-1", None, minute=1)
    with pytest.raises(ValueError, match="timezone-aware"):
        store.part_installs(since=datetime(2026, 3, 1, 6, 0))
    with pytest.raises(ValueError, match="until .* must be later than since"):
        store.part_installs(since=T0, until=T0)
    with pytest.raises(ValueError, match="limit"):
        store.part_installs(limit=0)
    with pytest.raises(ValueError, match="sha256 must be 64 hexadecimal digits"):
        store.add_image(cid, CycleStep.SHOOT, name="x", uri="x.png", sha256="abc")
    with pytest.raises(ValueError, match="size_bytes"):
        store.add_image(cid, CycleStep.SHOOT, name="x", uri="x.png", size_bytes=-1)
    # Without a digest (as every caller before schema version 5): recorded, both None.
    ref = store.add_image(cid, CycleStep.SHOOT, name="old", uri="old.png")
    assert (ref.sha256, ref.size_bytes) == (None, None)
    upper = store.add_image(cid, CycleStep.SHOOT, name="up", uri="up.png", sha256="AB" * 32, size_bytes=3)
    assert upper.sha256 == "ab" * 32 and store.cycle(cid).images[-1].sha256 == "ab" * 32
