"""The nine-point map is checked against the camera model at commissioning: a mirrored map (det < 0:
ReverseX/ReverseY turned on after the camera calibration, an offset's sign flipped) or one whose scale is off
the pixel scale s (eq. 15) is refused, naming the check and its figures; the twin's real map is accepted.

The data are the seeded twin's own nine-point collection (the teaching tests' commissioning chain), changed
as such a fault would change them: the corner's pixel u flipped, the robot's offsets mirrored or scaled by 10 %.
"""

from __future__ import annotations

import dataclasses
import functools
import re
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
from calib_test_support import config
from test_calib_teach import _taught, _taught_dataset  # the seeded twin commissioned once per test process, shared

from cellctl.calibration import compute_recipe
from cellctl.calibration.calibration_set import CalibrationSet
from cellctl.calibration.compute import Outcome
from cellctl.calibration.compute_recipe import compute_nine_point
from cellctl.calibration.dataset import Dataset, pose_array
from cellctl.calibration.errors import CalibrationRefused
from cellctl.config.feature import shot_feature
from cellctl.vision.feature import FeatureShot, detect_feature


def _true_mm_per_px() -> float:
    cfg = config()
    return cfg.process.working_distance_mm / cfg.sim.camera.intrinsics.fx


@functools.lru_cache(maxsize=1)
def _nine_point() -> tuple[CalibrationSet, Dataset, tuple[FeatureShot, ...]]:
    """The commissioned set, its nine-point dataset and the corner found in each of its images (in view order)."""
    cal, ds = _taught_dataset("pixel_map", "nine_point")
    feature = shot_feature(config())
    shots = tuple(
        detect_feature(ds.image(v["image"]), cal.lens(), config().vision, feature.arc, corner_radius=feature.corner_radius)
        for v in ds.manifest["views"]
    )
    assert all(s.features is not None for s in shots)
    return cal, ds, shots


def _with_corners(monkeypatch: pytest.MonkeyPatch, change: Callable[[float, float], tuple[float, float]]) -> None:
    """compute_nine_point sees the real corners of its views, each changed by ``change(u, v)``."""
    _, _, shots = _nine_point()
    it: Iterator[FeatureShot] = iter(shots)

    def detect(*args: Any, **kwargs: Any) -> FeatureShot:
        shot = next(it)
        assert shot.features is not None
        u, v = change(shot.features.u_px, shot.features.v_px)
        return dataclasses.replace(shot, features=dataclasses.replace(shot.features, u_px=u, v_px=v))

    monkeypatch.setattr(compute_recipe, "detect_feature", detect)


def _with_offsets(ds: Dataset, cal: CalibrationSet, gain: tuple[float, float]) -> Dataset:
    """The dataset with the robot's reported offsets from the taught pose along T0's x and y times ``gain``."""
    taught = cal.taught()
    R, ref = taught.T0[:3, :3], taught.C_Pos_0[:3, 3]
    manifest = {**ds.manifest, "views": []}
    for v in ds.manifest["views"]:
        T = pose_array(v["T_B_H"], "T_B_H").copy()
        o = R.T @ (T[:3, 3] - ref)
        T[:3, 3] = ref + R @ np.array([o[0] * gain[0], o[1] * gain[1], o[2]])
        manifest["views"].append({**v, "T_B_H": T.tolist()})
    return Dataset(ds.root, manifest)


def _apart_percent(err: CalibrationRefused) -> float:
    m = re.search(r"(\d+\.\d)% apart", err.detail)
    assert m is not None, err.detail
    return float(m.group(1))


def _refused(ds: Dataset, cal: CalibrationSet) -> CalibrationRefused:
    with pytest.raises(CalibrationRefused) as err:
        compute_nine_point(ds, cal, config())
    assert err.value.part == "pixel_map"
    return err.value


def test_the_twins_real_nine_point_data_are_accepted_within_the_true_scale(monkeypatch: pytest.MonkeyPatch) -> None:
    cal, ds, _ = _nine_point()
    _with_corners(monkeypatch, lambda u, v: (u, v))
    out: Outcome = compute_nine_point(ds, cal, config())
    amap, _ = out.detail
    assert np.linalg.det(amap.linear) > 0
    sv = np.linalg.svd(amap.linear, compute_uv=False)
    assert np.all(np.abs(sv / _true_mm_per_px() - 1.0) < 0.005)  # every direction within 0.5 % of the twin's truth
    assert abs(out.quality["map_mm_per_px"] / _true_mm_per_px() - 1.0) < 0.003


def test_a_mirrored_pixel_u_is_refused_naming_the_check(monkeypatch: pytest.MonkeyPatch) -> None:
    cal, ds, _ = _nine_point()
    width = cal.image_size()[0]
    _with_corners(monkeypatch, lambda u, v: (width - 1.0 - u, v))  # the camera's ReverseX turned on
    err = _refused(ds, cal)
    assert err.reason == "mirrored_map" and "det" in err.detail and "ReverseX" in err.detail


def test_a_flipped_offset_sign_is_refused_as_mirrored() -> None:
    cal, ds, _ = _nine_point()
    err = _refused(_with_offsets(ds, cal, (-1.0, 1.0)), cal)
    assert err.reason == "mirrored_map" and "offsets" in err.detail


def test_a_map_ten_percent_off_the_pixel_scale_is_refused_with_its_figures(monkeypatch: pytest.MonkeyPatch) -> None:
    cal, ds, _ = _nine_point()
    err = _refused(_with_offsets(ds, cal, (1.1, 1.1)), cal)  # the offsets read 10 % long
    assert err.reason == "map_scale" and 9.5 < _apart_percent(err) < 10.5, err.detail
    s_board = _taught()[2].values["scale_mm_per_px"]  # the pixel scale s of the same data
    assert f"s (eq. 15, the scale board) is {s_board:.6f} mm/px" in err.detail and "square size" in err.detail
    cx, cy = (np.asarray(cal.image_size(), dtype=float) - 1.0) / 2.0
    _with_corners(monkeypatch, lambda u, v: (cx + 1.1 * (u - cx), cy + 1.1 * (v - cy)))  # the image 10 % larger
    err = _refused(ds, cal)
    assert err.reason == "map_scale" and 8.6 < _apart_percent(err) < 9.6, err.detail
