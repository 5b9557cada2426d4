"""The calibration set: validation on load, history, readiness checks, and dataset integrity."""

from __future__ import annotations

import json
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest
from calib_test_support import NOW, INPUTS, VALUES

from cellctl.calibration.calibration_set import (
    CalibrationSetError,
    CalibrationStore,
    load_calibration_set,
    make_part,
)
from cellctl.calibration.dataset import DatasetError, read_dataset, write_dataset
from cellctl.calibration.readiness import check_ready



def _full_store(root: Path) -> CalibrationStore:
    store = CalibrationStore(root)
    for name in ("camera", "hand_eye", "laser", "teaching", "pixel_map"):
        cur = store.current()
        inputs = {dep: cur.part(dep).id for dep in INPUTS[name]} if cur else {}
        part = make_part(name, values=VALUES[name], method="test", when=NOW, valid_days=90.0, quality={"rms": np.float64(0.1)}, inputs=inputs)
        store.commit(name, part, now=NOW)
    return store


def test_a_complete_set_is_ready_and_round_trips(tmp_path: Path) -> None:
    store = _full_store(tmp_path)
    cal = store.current()
    assert cal is not None and cal.version == 5
    assert check_ready(cal, NOW + timedelta(days=1)) == []
    again = load_calibration_set(tmp_path / "set-000005.json")
    assert again == cal
    np.testing.assert_allclose(cal.camera_matrix()[0, 0], 5249.6)
    assert cal.taught().T0.shape == (4, 4) and cal.template()["u_d"] == 1014.0
    # History: every version kept, each one a valid set, the pointer on the newest.
    assert store.versions() == [1, 2, 3, 4, 5]
    assert [row["parts"]["camera"] for row in store.history()] == ["ok"] * 5
    assert store.load(1).part("hand_eye") is None
    assert (tmp_path / "current").read_text().strip() == "set-000005.json"


def test_missing_failed_expired_stale_and_future_parts_stop_production(tmp_path: Path) -> None:
    store = _full_store(tmp_path)
    # Expired after 90 days.
    problems = check_ready(store.current(), NOW + timedelta(days=91))
    assert len(problems) == 5 and all("expired" in p for p in problems)
    # A new camera makes hand-eye, teaching and the pixel map stale (computed with the old one).
    K2 = dict(VALUES["camera"], K=[[5250.0, 0.0, 1014.0], [0.0, 5249.0, 1012.0], [0.0, 0.0, 1.0]])
    store.commit("camera", make_part("camera", values=K2, method="test", when=NOW + timedelta(hours=1), valid_days=90.0), now=NOW)
    stale = check_ready(store.current(), NOW + timedelta(days=1))
    assert sorted(p.split(":")[0] for p in stale) == ["hand_eye", "pixel_map", "teaching"]
    assert all("computed with camera" in p and "run `" in p for p in stale)
    # A failed laser calibration is kept with its reason and blocks production.
    failed = make_part("laser", values=None, method="test", when=NOW, valid_days=90.0, failure="plane seen from too few directions")
    store.commit("laser", failed, now=NOW)
    problems = check_ready(store.current(), NOW + timedelta(days=1))
    assert any(p.startswith("laser: the last calibration failed (plane seen from too few directions)") for p in problems)
    # A part dated further in the future than its validity points at a wrong clock.
    assert any("in the future" in p for p in check_ready(store.current(), NOW - timedelta(days=91)))
    # Nothing at all.
    assert "no calibration set" in check_ready(None, NOW)[0]
    with pytest.raises(CalibrationSetError, match="laser is failed"):
        store.current().laser_ray()


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d["parts"]["camera"]["values"]["K"].__setitem__(2, [0, 0, 2]), "parts.camera.values.K"),
        (lambda d: d["parts"]["laser"]["values"].__setitem__("l", [1.0, 0.1, 0.0]), "parts.laser.values.l: Value error, l must be a unit vector"),
        (lambda d: d["parts"]["hand_eye"]["values"]["T_H_C"][0].__setitem__(0, 2.0), "parts.hand_eye.values.T_H_C"),
        (lambda d: d["parts"]["teaching"]["values"].pop("g_Pos_0"), "parts.teaching.values.g_Pos_0: required field is missing"),
        (lambda d: d["parts"]["pixel_map"].__setitem__("colour", "red"), "parts.pixel_map.colour: unknown field"),
        (lambda d: d["parts"]["camera"].__setitem__("calibrated_utc", "2026-01-15T12:00:00"), "parts.camera.calibrated_utc"),
        (lambda d: d["parts"]["laser"].__setitem__("status", "failed"), "parts.laser"),
    ],
)
def test_a_damaged_file_is_refused_naming_the_field(tmp_path: Path, edit, message: str) -> None:  # type: ignore[no-untyped-def]
    store = _full_store(tmp_path)
    path = tmp_path / "set-000005.json"
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))
    with pytest.raises(CalibrationSetError) as err:
        store.current()
    assert message.replace("Value error, ", "") in str(err.value)


def test_not_a_calibration_set_is_refused(tmp_path: Path) -> None:
    p = tmp_path / "x.json"
    p.write_text("{not json")
    with pytest.raises(CalibrationSetError, match="not valid JSON"):
        load_calibration_set(p)
    p.write_text(json.dumps({"format": "something-else"}))
    with pytest.raises(CalibrationSetError, match="not a calibration set"):
        load_calibration_set(p)


def test_a_dataset_image_changed_after_recording_is_refused(tmp_path: Path) -> None:
    img = np.full((8, 8), 100, dtype=np.uint8)
    ds = write_dataset(tmp_path / "ds", "board_views", {"views": []}, {"a.png": img})
    ref = ds.ref()
    assert len(ref.manifest_sha256) == 64
    again = read_dataset(tmp_path / "ds", "board_views")
    np.testing.assert_array_equal(again.image("a.png"), img)
    import cv2

    cv2.imwrite(str(tmp_path / "ds" / "a.png"), np.zeros((8, 8), np.uint8))
    with pytest.raises(DatasetError, match="changed since it was recorded"):
        again.image("a.png")
    with pytest.raises(DatasetError, match="needs a 'laser_plane' dataset"):
        read_dataset(tmp_path / "ds", "laser_plane")
    with pytest.raises(DatasetError, match="not empty"):
        write_dataset(tmp_path / "ds", "board_views", {}, {})
