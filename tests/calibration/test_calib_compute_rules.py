"""From a dataset to a part: which inputs compute_* takes, against datasets of known truth.

The laser dataset holds the synthetic readings of test_calib_laser_rules (exact, r and l of eq. 19) as the cell
records them; the calibration set is a stand-in whose parts have a status.
"""

from __future__ import annotations

import types

import numpy as np
import pytest
from calib_test_support import config
from test_calib_laser_rules import L_TRUE, R_TRUE, _readings

from cellctl.calibration.compute import compute_laser, need_part
from cellctl.calibration.dataset import pose_list
from cellctl.calibration.errors import CalibrationRefused
from cellctl.geometry.rotation import angle_between_vectors


def _laser_dataset(rows: list[dict[str, object]]) -> types.SimpleNamespace:
    manifest = {"readings": rows, "sensor_range_mm": [250.0, 450.0], "r_nominal": [40.0, -40.0, 90.0], "l_nominal": [1.0, 0.0, 0.0]}
    return types.SimpleNamespace(manifest=manifest, root="synthetic")


def test_a_reading_whose_status_is_not_ok_is_left_out_even_with_a_distance() -> None:
    # A sensor out of range may still report a number (the LK-G's clamp at the range's end): only "ok" readings count.
    H, d, g = _readings(120, np.random.default_rng(11), groups=4, group_shift_mm=0.3)
    rows: list[dict[str, object]] = [
        {"T_B_H": pose_list(h), "distance_mm": float(x), "status": "ok", "group": int(k)} for h, x, k in zip(H, d, g)
    ]
    for k in range(0, 120, 20):  # six readings the sensor flagged, each with the clamp value
        rows.insert(k, {"T_B_H": pose_list(H[k]), "distance_mm": 450.0, "status": "over_range_far", "group": int(g[k])})
    o = compute_laser(_laser_dataset(rows), config())  # type: ignore[arg-type]
    assert o.quality["readings_used"] == 120
    assert o.quality["readings_without_value"] == 6
    assert np.linalg.norm(np.asarray(o.values["r"]) - R_TRUE) < 1e-3
    assert np.degrees(angle_between_vectors(o.values["l"], L_TRUE)) < 1e-4


def test_a_part_that_failed_is_not_built_on() -> None:
    failed = types.SimpleNamespace(status="failed", id="camera-7")
    cal = types.SimpleNamespace(part=lambda name, recipe=None: failed)
    with pytest.raises(CalibrationRefused) as err:
        need_part(cal, "hand_eye", "camera")  # type: ignore[arg-type]
    assert err.value.reason == "missing_input"
    assert "camera is failed" in str(err.value)
    ok = types.SimpleNamespace(part=lambda name, recipe=None: types.SimpleNamespace(status="ok", id="camera-8"))
    assert need_part(ok, "hand_eye", "camera") == "camera-8"  # type: ignore[arg-type]
