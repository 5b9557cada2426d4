"""What teach and calibrate status print: plain numbers, and no part called ok that the readiness check names."""

from __future__ import annotations

import argparse
from datetime import datetime, timezone
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

import cellctl.commissioning.cli as ccli
from cellctl.calibration.calibration_set import PART_NAMES
from cellctl.calibration.summary import summary_lines


def _pose(x: float, y: float, z: float) -> list[list[float]]:
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T.tolist()


def test_teaching_summary_prints_plain_vectors_and_counts() -> None:
    values = {"C_Pos_0": _pose(1358.1, -1074.77, 1901.38), "T0": _pose(1699.91, -1000.13, 1800.1),
              "g_Pos_0": _pose(1580.0, 0.118, 1050.0), "u_d": 1017.0, "v_d": 1011.2, "theta_d": -1e-4}  # fmt: skip
    quality = {"wall_rms_mm": 0.017, "spots_used": 6, "corner_sigma_px": 0.04, "T0_from_layout_mm": [0.1, 0.1, 0.1],
               "g_Pos_0_installs": {"count": 3, "spread_mm": 0.11, "spread_deg": 0.05},
               "twin_truth": {"T0_error_mm": [0.13, -0.098, -0.095], "T0_error_deg": [0.0046, 0.0011, -0.006]}}  # fmt: skip
    text = "\n".join(summary_lines("teaching", values, quality))
    assert "C_Pos_0 at (1358.10, -1074.77, 1901.38) mm" in text
    assert "g_Pos_0 at (1580.00, 0.12, 1050.00) mm, the mean of 3 hand-guided installs" in text
    assert "T0 (0.130, -0.098, -0.095) mm" in text
    assert "[" not in text and "e+0" not in text  # no numpy array layout


class _Store:
    root = Path("/srv/cell/var/calibration")

    def __init__(self, cal: Any) -> None:
        self._cal = cal

    def current(self) -> Any:
        return self._cal

    def history(self) -> list[dict[str, Any]]:
        return [{"version": v, "created_utc": "2026-01-01T00:00:00Z", "note": "n"} for v in (1, 2)]


def test_calibrate_status_does_not_call_a_stale_part_ok(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    when = datetime(2026, 1, 1, tzinfo=timezone.utc)
    parts = {n: SimpleNamespace(status="ok", calibrated_utc=when, id=f"{n}-1", failure=None) for n in PART_NAMES}
    cal = SimpleNamespace(version=2, part=parts.get)
    stale = "teaching: computed with hand_eye hand_eye-0, but the set now holds hand_eye hand_eye-1; run `cellctl teach` again"
    monkeypatch.setattr(ccli, "_store", lambda args: _Store(cal))
    monkeypatch.setattr(ccli, "check_ready", lambda cal, now, **_: [stale])
    assert ccli.cmd_status(argparse.Namespace(history=False, store=None, workdir=Path("/srv/cell"))) == 1
    out = capsys.readouterr().out
    assert "set version 2 in use, 2 version(s) kept" in out
    rows = {line.split()[0]: line.split()[1] for line in out.splitlines() if line.startswith("  ") and line.split()[0] in PART_NAMES}
    assert rows["teaching"] == "NEEDS" and rows["camera"] == "ok" and rows["hand_eye"] == "ok"
    assert out.rstrip().endswith(stale)
