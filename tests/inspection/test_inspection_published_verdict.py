"""Rules of what a cycle publishes that only a mutation run showed unguarded: the tolerance verdict per axis,
a rejected part's summary (what the PLC, OPC UA and MQTT read) and a finished cycle's final result."""

from __future__ import annotations

from pathlib import Path

import pytest

from cellctl.cell.outcome import result_message, summarize
from cellctl.domain import AlarmCode, InstallDeviation
from cellctl.inspection.deviation import MeasuredDeviation
from cellctl.store import CellStore, CycleRequest, CycleStateError


def _md(**kw: float) -> MeasuredDeviation:
    d = dict(dx_mm=0.0, dy_mm=0.0, dz_mm=0.0, drx_deg=0.0, dry_deg=0.0, drz_deg=0.0)
    d.update(kw)
    return MeasuredDeviation(InstallDeviation(**d), 5.0, 5.0, None)  # type: ignore[arg-type]


# insp_orientation_checked_against_mm: a rotation is judged against +-orientation_deg, not +-position_mm
def test_a_rotation_within_the_orientation_tolerance_is_ok_even_past_the_position_figure() -> None:
    assert _md(drx_deg=0.8).outside(0.5, 1.0) == []
    assert _md(drx_deg=1.2).outside(0.5, 1.0) == ["drx_deg=+1.200"]


# insp_dz_not_checked: a glass recessed past the tolerance (dz) is a reject
def test_a_glass_recessed_past_the_tolerance_is_outside() -> None:
    assert _md(dz_mm=0.6).outside(0.5, 1.0) == ["dz_mm=+0.600"]


def _done_cycle(tmp_path: Path, result: dict[str, object]) -> tuple[CellStore, int]:
    """A store holding one cycle, finished with ``result``."""
    store = CellStore.open(tmp_path / "cell.db")
    cid = store.submit_cycle(CycleRequest(recipe="side-window", part_id="7", car_id="C", source="plc"),
                             scope="plc", key="7", actor="plc").cycle.id  # fmt: skip
    store.start_cycle(cid)
    store.complete_cycle(cid, result=result)
    return store, cid


# insp_part_nok_summarized_ok: a done cycle whose part was measured outside the tolerance is not OK for the PLC/MQTT/OPC UA
def test_a_part_measured_outside_the_tolerance_is_published_nok_with_1311(tmp_path: Path) -> None:
    m = dict(dx_mm=-0.8, dy_mm=0.0, dz_mm=0.0, drx_deg=0.0, dry_deg=0.0, drz_deg=0.0)
    store, cid = _done_cycle(tmp_path, {"ok": False, "part_ok": False, "error_code": int(AlarmCode.INSTALL_OUT_OF_TOLERANCE),
                                        "not_ok_reason": "dx_mm=-0.800", "measured_deviation": m,
                                        "correction_mm": [0, 0, 0], "correction_deg": [0, 0, 0], "cycle_time_s": 40.0})  # fmt: skip
    try:
        s = summarize(store.cycle(cid))
        assert s is not None and s.ok is False and s.error_code == int(AlarmCode.INSTALL_OUT_OF_TOLERANCE)
    finally:
        store.close()


# store_done_cycle_can_be_failed: a finished cycle's result is final
def test_a_done_cycle_cannot_be_failed_afterwards(tmp_path: Path) -> None:
    store, cid = _done_cycle(tmp_path, {"ok": True})
    try:
        with pytest.raises(CycleStateError):
            store.fail_cycle(cid, error="late failure")
        assert store.cycle(cid).result == {"ok": True}
    finally:
        store.close()


# The plant's result (MQTT, OPC UA, MES) carries the record's corrections bit for bit: a trip through radians and
# back changes about one figure in seven in its last bit (CI saw 0.02670428061002395 published as ...23952).
def test_the_published_result_carries_the_records_corrections_bit_for_bit(tmp_path: Path) -> None:
    deg = [0.39568644409932835, 0.02670428061002395, -0.250696893740199]
    mm = [15.413399526875764, -5.3948644669169425, -1.8491432142611757]
    store, cid = _done_cycle(tmp_path, {"ok": True, "error_code": 0, "correction_mm": mm, "correction_deg": deg,
                                        "cycle_time_s": 40.0})  # fmt: skip
    try:
        message = result_message(store.cycle(cid))
        assert message is not None
        assert message["correction_deg"] == deg and message["correction_mm"] == mm
    finally:
        store.close()
