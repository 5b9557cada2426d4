"""Store: cycles, steps, idempotency keys, alarms round trip."""

from __future__ import annotations

import itertools
import sqlite3
from collections.abc import Callable
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import pytest

from cellctl.cell.alarms import AlarmCode, AlarmManager
from cellctl.cell.tags import CycleStep, PackMLCommand
from cellctl.store import schema
from cellctl.store import (
    CellStore,
    CycleRequest,
    CycleState,
    CycleStateError,
    IdempotencyConflict,
    IdempotencyInFlight,
    InstallAlreadyStarted,
    StoreError,
    UnknownCycle,
)

T0 = datetime(2026, 11, 22, 8, 0, tzinfo=timezone.utc)


def stepping_clock(step_s: float = 0.5) -> Callable[[], datetime]:
    n = itertools.count()
    return lambda: T0 + timedelta(seconds=step_s * next(n))


@pytest.fixture
def store(tmp_path: Path) -> CellStore:
    s = CellStore.open(tmp_path / "cell.db", clock=stepping_clock())
    yield s
    s.close()


REQ = CycleRequest(recipe="side-window-A", part_id="P-0001", car_id="CAR-17", source="rest:10.0.0.9")


def test_opens_in_wal_with_full_sync_and_refuses_bad_paths(store: CellStore, tmp_path: Path) -> None:
    info = store.info()
    assert (info.journal_mode, info.synchronous, info.schema_version) == ("wal", "FULL", len(schema.MIGRATIONS))
    with pytest.raises(ValueError, match="file path"):
        CellStore.open(":memory:")
    with pytest.raises(StoreError, match="does not exist"):
        CellStore.open(tmp_path / "missing" / "cell.db")
    with pytest.raises(ValueError, match="synchronous"):
        CellStore.open(tmp_path / "x.db", synchronous="OFF")  # type: ignore[arg-type]


def test_same_key_same_request_gives_the_same_cycle(store: CellStore) -> None:
    first = store.submit_cycle(REQ, scope="rest", key="k-1", actor="line")
    retry = store.submit_cycle(
        CycleRequest(REQ.recipe, REQ.part_id, REQ.car_id, source="rest:10.0.0.10"), scope="rest", key="k-1", actor="line"
    )
    assert first.created and not retry.created and retry.cycle.id == first.cycle.id
    assert store.cycle_counts()[CycleState.QUEUED] == 1
    other_scope = store.submit_cycle(REQ, scope="plc", key="k-1", actor="plc")
    assert other_scope.created and other_scope.cycle.id != first.cycle.id


def test_same_key_different_request_is_a_clear_conflict(store: CellStore) -> None:
    store.submit_cycle(REQ, scope="rest", key="k-1", actor="line")
    with pytest.raises(IdempotencyConflict, match=r"part_id 'P-0001' then 'P-0002'") as err:
        store.submit_cycle(CycleRequest(REQ.recipe, "P-0002", REQ.car_id), scope="rest", key="k-1", actor="line")
    assert err.value.differences == {"part_id": ("P-0001", "P-0002")}
    assert store.cycle_counts()[CycleState.QUEUED] == 1


def test_bad_requests_are_refused_naming_the_field() -> None:
    with pytest.raises(ValueError, match="recipe must not be empty"):
        CycleRequest(recipe=" ", part_id="P")
    with pytest.raises(ValueError, match="part_id is 200 characters"):
        CycleRequest(recipe="r", part_id="x" * 200)
    with pytest.raises(ValueError, match="car_id contains control characters"):
        CycleRequest(recipe="r", part_id="p", car_id="a\nb")
    with pytest.raises(ValueError, match="part_id must be a string"):
        CycleRequest(recipe="r", part_id=7)  # type: ignore[arg-type]


def test_full_cycle_record(store: CellStore) -> None:
    cid = store.submit_cycle(REQ, scope="rest", key="k", actor="line").cycle.id
    store.start_cycle(cid)
    for step in (CycleStep.CALIBRATE, CycleStep.ALIGN):
        store.begin_step(cid, step)
        store.finish_step(cid, step, ok=True, figures={"rms_mm": np.float64(0.042), "n": np.int64(6)})
    for attempt in (1, 2):  # compensate's verification shots
        assert store.begin_step(cid, CycleStep.SHOOT).attempt == attempt
        store.add_image(cid, CycleStep.SHOOT, name=f"shot{attempt}", uri=f"images/{cid}/shot{attempt}.png")
        store.finish_step(cid, CycleStep.SHOOT, ok=attempt == 2, figures={"offset_mm": np.array([0.8, -0.1 * attempt])})
    store.begin_step(cid, CycleStep.INSTALL)
    store.finish_step(cid, CycleStep.INSTALL, ok=True, figures={})
    done = store.complete_cycle(cid, result={"dx_mm": 0.12, "ok": True}, true_error={"position_mm": 0.21})
    assert done.state == CycleState.DONE and done.current_step == CycleStep.NONE
    assert done.result == {"dx_mm": 0.12, "ok": True} and done.true_error == {"position_mm": 0.21}
    assert [(s.step, s.attempt, s.ok) for s in done.steps] == [
        (CycleStep.CALIBRATE, 1, True), (CycleStep.ALIGN, 1, True), (CycleStep.SHOOT, 1, False),
        (CycleStep.SHOOT, 2, True), (CycleStep.INSTALL, 1, True)]  # fmt: skip
    assert done.steps[1].figures == {"rms_mm": 0.042, "n": 6}
    assert done.steps[3].figures == {"offset_mm": [0.8, -0.2]}
    # The stepping clock advances 0.5 s per reading; a shot also reads it to file its image.
    assert [s.duration_s for s in done.steps] == pytest.approx([0.5, 0.5, 1.0, 1.0, 0.5])
    assert [i.name for i in done.images] == ["shot1", "shot2"] and done.install_started
    assert done.request == REQ and done.duration_s is not None and done.duration_s > 0
    assert [c.id for c in store.cycles()] == [cid] and store.cycles(state=CycleState.FAILED) == []


def test_cycle_state_rules(store: CellStore) -> None:
    cid = store.submit_cycle(REQ, scope="rest", key="k", actor="line").cycle.id
    with pytest.raises(CycleStateError, match="a step can only begin in a running cycle"):
        store.begin_step(cid, CycleStep.ALIGN)
    with pytest.raises(CycleStateError, match="it can complete only when running"):
        store.complete_cycle(cid, result={})
    store.start_cycle(cid)
    with pytest.raises(CycleStateError, match="can start only when queued"):
        store.start_cycle(cid)
    with pytest.raises(CycleStateError, match="never begun"):
        store.finish_step(cid, CycleStep.ALIGN, ok=True, figures={})
    store.begin_step(cid, CycleStep.ALIGN)
    with pytest.raises(ValueError, match="NaN or infinity"):
        store.finish_step(cid, CycleStep.ALIGN, ok=True, figures={"rms_mm": float("nan")})
    with pytest.raises(ValueError, match="cannot be stored as JSON"):
        store.finish_step(cid, CycleStep.ALIGN, ok=True, figures={"thing": object()})
    store.finish_step(cid, CycleStep.ALIGN, ok=False, figures={"rms_mm": 0.9}, error="plane rms over 0.2 mm")
    with pytest.raises(CycleStateError, match="already finished"):
        store.finish_step(cid, CycleStep.ALIGN, ok=True, figures={})
    failed = store.fail_cycle(cid, error="alignment NOK")
    assert failed.state == CycleState.FAILED and failed.current_step == CycleStep.ALIGN
    with pytest.raises(UnknownCycle, match="no cycle with id 999"):
        store.cycle(999)
    with pytest.raises(UnknownCycle):
        store.begin_step(999, CycleStep.ALIGN)


def test_an_ended_cycle_begins_no_step(store: CellStore) -> None:
    # A step begun under a done, failed or interrupted record (a late retry, a second process) would write into an
    # ended cycle, and an install step there would be a robot commanded for a cycle already reported.
    ends: dict[str, Callable[[int], object]] = {
        "done": lambda cid: store.complete_cycle(cid, result={}),
        "failed": lambda cid: store.fail_cycle(cid, error="alignment NOK"),
        "interrupted": lambda cid: store.recover(),
    }
    for state, end in ends.items():
        cid = store.submit_cycle(REQ, scope="rest", key=state, actor="line").cycle.id
        store.start_cycle(cid)
        end(cid)
        assert store.cycle(cid).state.value == state
        for step in (CycleStep.ALIGN, CycleStep.INSTALL):
            with pytest.raises(CycleStateError, match=f"is {state}, a step can only begin in a running cycle"):
                store.begin_step(cid, step)
        assert store.cycle(cid).install_started_at is None


def test_install_marker_is_written_once_and_cannot_be_undone(store: CellStore, tmp_path: Path) -> None:
    cid = store.submit_cycle(REQ, scope="rest", key="k", actor="line").cycle.id
    store.start_cycle(cid)
    store.begin_step(cid, CycleStep.INSTALL)
    with pytest.raises(InstallAlreadyStarted, match="never repeated"):
        store.begin_step(cid, CycleStep.INSTALL)
    raw = sqlite3.connect(tmp_path / "cell.db")
    with pytest.raises(sqlite3.IntegrityError, match="install-started marker"):
        raw.execute("UPDATE cycles SET install_started_at = NULL WHERE id = ?", (cid,))
    raw.close()


def test_command_idempotency_replays_and_refuses(store: CellStore) -> None:
    req = {"command": "reset"}
    assert store.claim_key("rest-cmd", "c1", req) is None
    with pytest.raises(IdempotencyInFlight, match="still in progress"):
        store.claim_key("rest-cmd", "c1", req)
    store.complete_key("rest-cmd", "c1", {"status": 409, "detail": "Reset refused in Execute"})
    replay = store.claim_key("rest-cmd", "c1", req)
    assert replay is not None and replay.response == {"status": 409, "detail": "Reset refused in Execute"}
    with pytest.raises(IdempotencyConflict, match="command 'reset' then 'start'"):
        store.claim_key("rest-cmd", "c1", {"command": "start"})
    with pytest.raises(StoreError, match="not an open claim"):
        store.complete_key("rest-cmd", "c1", {})
    assert store.claim_key("rest-cmd", "c2", req) is None
    store.release_key("rest-cmd", "c2")  # the handler did nothing: a retry may run it
    assert store.claim_key("rest-cmd", "c2", req) is None
    cid = store.submit_cycle(REQ, scope="rest-cmd", key="c9", actor="line").cycle.id
    with pytest.raises(IdempotencyConflict):  # a cycle's key is not reusable for a command
        store.claim_key("rest-cmd", "c9", req)
    assert store.forget_keys("rest-cmd", created_before=T0 + timedelta(days=1)) == 2
    assert store.submit_cycle(REQ, scope="rest-cmd", key="c9", actor="line").cycle.id != cid


async def test_alarm_records_round_trip(store: CellStore) -> None:
    am = AlarmManager(clock=stepping_clock())
    am.subscribe(lambda ev: store.save_alarm(ev.alarm))
    a = await am.raise_alarm(AlarmCode.CORNER_NOT_FOUND, source="vision", detail="no edge", value=3, cycle_id=4)
    b = await am.raise_alarm(AlarmCode.LASER_LOST, source="laser")
    am.acknowledge(a.uid, by="op")
    saved = {x.uid: x for x in store.alarms()}
    assert saved[a.uid] == am.get(a.uid) and saved[b.uid] == am.get(b.uid)
    assert [x.uid for x in store.alarms(active_only=True)] == [b.uid]
    assert saved[a.uid].ack_by == "op" and saved[a.uid].reaction is None
    assert PackMLCommand.HOLD not in {x.reaction for x in saved.values()}  # no machine: nothing issued


async def test_recovery_closes_the_alarms_a_stopped_process_left_active(store: CellStore) -> None:
    # The process that raised them is gone: what still holds is raised anew by the watchdog, so none stays active.
    am = AlarmManager(clock=stepping_clock())
    am.subscribe(lambda ev: store.save_alarm(ev.alarm))
    a = await am.raise_alarm(AlarmCode.LASER_LOST, source="laser")
    b = await am.raise_alarm(AlarmCode.CAMERA_LOST, source="camera")
    am.clear(AlarmCode.CAMERA_LOST, source="camera")
    assert [x.uid for x in store.alarms(active_only=True)] == [a.uid]
    assert store.recover().alarms_closed == 1
    assert store.alarms(active_only=True) == []
    closed = {x.uid: x for x in store.alarms()}
    assert closed[a.uid].cleared_at is not None and closed[b.uid].cleared_at == am.get(b.uid).cleared_at
    assert store.recover().alarms_closed == 0
