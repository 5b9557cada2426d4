"""What a finished cycle reports: the record's result fields, and the outcome the PLC and the API publish.

A cycle that installed and measured its glass is done; whether the part is OK is the measured
deviation against ``[process.tolerance]``. A part measured outside it is done but not OK, with
alarm 1311 as its error code and the figures outside named in the reason.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from cellctl.cell.cycle_values import CycleResult
from cellctl.config.cell import ToleranceConfig
from cellctl.domain import DEVIATION_KEYS, AlarmCode, CycleStep, InstallDeviation
from cellctl.store import CycleRecord, CycleState


@dataclass(frozen=True)
class CycleSummary:
    """The outcome of a finished cycle in the units the PLC and the API publish.

    ``ok`` is False for a failed cycle and for a part measured outside the tolerance;
    ``measured`` is the inspection's six figures (None when the cycle did not measure its glass);
    the corrections are zeros when the cycle computed none (the PLC registers' meaning with ``ok`` false).
    """

    cycle_id: int
    ok: bool
    error_code: int
    error: str | None
    correction_mm: tuple[float, float, float]
    correction_rad: tuple[float, float, float]
    cycle_time_s: float
    measured: InstallDeviation | None = None
    calibration_version: str | None = None


def part_verdict(result: CycleResult, tolerance: ToleranceConfig) -> str | None:
    """Why the installed part is not OK (the figures outside the tolerance), or None when it is or was not measured."""
    if result.measured is None:
        return None
    outside = result.measured.outside(tolerance.position_mm, tolerance.orientation_deg)
    if not outside:
        return None
    return (
        f"installed glass measured outside the tolerance (+-{tolerance.position_mm:g} mm, +-{tolerance.orientation_deg:g} deg): "
        + ", ".join(outside)
    )


def result_fields(result: CycleResult, cycle_time_s: float, *, not_ok: str | None = None) -> dict[str, Any]:
    """The ``result`` of a done cycle's record (JSON-ready)."""
    fields: dict[str, Any] = {
        "ok": not_ok is None,
        "error_code": 0 if not_ok is None else int(AlarmCode.INSTALL_OUT_OF_TOLERANCE),
        "correction_mm": [float(v) for v in result.workpiece_correction_mm],
        "correction_deg": [float(np.degrees(v)) for v in result.workpiece_correction_rad],
        "shots": len(result.shots),
        "cycle_time_s": cycle_time_s,
        "measured_deviation": None if result.measured is None else result.measured.as_dict(),
        # the car body's wall as the alignment fitted it: normal . p = offset_mm (base frame, normal into the wall)
        "wall_plane_B": {
            "normal": [float(v) for v in result.alignment.wall.normal],
            "offset_mm": float(result.alignment.wall.offset),
        },
    }
    if result.measured is not None:
        fields["part_ok"] = not_ok is None
        fields["gaps_mm"] = {"top": result.measured.top_gap_mm, "right": result.measured.right_gap_mm}
    if not_ok is not None:
        fields["not_ok_reason"] = not_ok
    return fields


def measured_of(result: dict[str, Any]) -> InstallDeviation | None:
    """The measured six figures in a record's result, if it has them."""
    m = result.get("measured_deviation")
    if not isinstance(m, dict) or any(k not in m for k in DEVIATION_KEYS):
        return None
    return InstallDeviation(**{k: float(m[k]) for k in DEVIATION_KEYS})


def summarize(record: CycleRecord) -> CycleSummary | None:
    """The PLC/API outcome of a finished cycle record (None while it has not finished)."""
    if record.state not in (CycleState.DONE, CycleState.FAILED, CycleState.INTERRUPTED):
        return None
    res = dict(record.result or {})
    done = record.state is CycleState.DONE
    ok = done and res.get("part_ok", True) is not False
    code = 0 if ok else int(res.get("error_code") or AlarmCode.CYCLE_INTERRUPTED)
    mm = res.get("correction_mm") or [0.0, 0.0, 0.0]
    deg = res.get("correction_deg") or [0.0, 0.0, 0.0]
    return CycleSummary(
        record.id,
        ok,
        code,
        record.error if not done else res.get("not_ok_reason"),
        (float(mm[0]), float(mm[1]), float(mm[2])),
        (float(np.radians(deg[0])), float(np.radians(deg[1])), float(np.radians(deg[2]))),
        float(res.get("cycle_time_s") or 0.0),
        measured_of(res),
        calibration_version_of(record),
    )


def calibration_version_of(record: CycleRecord) -> str | None:
    """The calibration set version the cycle ran with: its result's, else its calibrate step's figures (older records)."""
    v = (record.result or {}).get("calibration_version")
    if v is None:
        for step in record.steps:
            cal = step.figures.get("calibration") if step.step is CycleStep.CALIBRATE else None
            if isinstance(cal, dict) and cal.get("version") is not None:
                v = cal["version"]
                break
    return None if v is None else str(v)


def recipe_settings_of(record: CycleRecord) -> str | None:
    """The id of the recipe's settings the cycle ran with (:mod:`cellctl.config.settings_id`), from its calibrate step."""
    v = (record.result or {}).get("recipe_settings")
    for step in record.steps if v is None else ():
        if step.step is CycleStep.CALIBRATE and step.figures.get("recipe_settings") is not None:
            return str(step.figures["recipe_settings"])
    return None if v is None else str(v)


def result_message(record: CycleRecord) -> dict[str, Any] | None:
    """A finished cycle's result as the plant reads it (OPC UA, MQTT, the MES export); None while it runs.

    Units are in the names: corrections and measured deviations in mm and deg, XYZ fixed angles (eq. 13).
    The corrections are None when the cycle computed none (it failed before compensating); the PLC's
    summary keeps zeros there, which its registers give with ``ok`` false.
    """
    s = summarize(record)
    if s is None:
        return None
    res = record.result or {}
    corrected = "correction_mm" in res
    req = record.request
    return {
        "cycle_id": record.id,
        "recipe": req.recipe,
        "part_id": req.part_id,
        "car_id": req.car_id,
        "source": req.source,
        "state": record.state.value,
        "ok": s.ok,
        "install_started": record.install_started_at is not None,  # the glass went into the opening: it counts as used
        "error_code": s.error_code,
        "reason": s.error or "",
        "measured_deviation": None if s.measured is None else asdict(s.measured),
        # the record's own figures: deg -> rad -> deg is not exact to the last bit, and the plant compares with REST
        "correction_mm": [float(v) for v in res["correction_mm"]] if corrected else None,
        "correction_deg": [float(v) for v in res.get("correction_deg") or (0.0, 0.0, 0.0)] if corrected else None,
        "cycle_time_s": s.cycle_time_s,
        "calibration_version": s.calibration_version,
        "recipe_settings": recipe_settings_of(record),
        "started_at": None if record.started_at is None else record.started_at.isoformat(),
        "finished_at": None if record.finished_at is None else record.finished_at.isoformat(),
    }
