"""Camera intrinsics the views cannot determine, or views from two lens settings, are refused (review r1, D1/D2).

Corners are synthesised from the twin's true lens (DESIGN 5, eq. 17) with 0.03 px noise; the
truth is that lens, so each test also shows how far off the result would be without the gate.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cellctl.calibration.board import BoardSpec
from cellctl.calibration.camera import ViewCorners, calibrate_camera
from cellctl.calibration.errors import CalibrationRefused
from cellctl.config.calibration_procedure import CameraCalibrationConfig

K = np.array([[5249.574, 0, 1014.700], [0, 5248.587, 1011.988], [0, 0, 1]])
D = np.array([-0.158, -0.0249, -0.0003, 0.0004, 0.0412])
OBJ = BoardSpec((11, 8), 10.0).object_points()
OBJ_C = OBJ - OBJ.mean(axis=0)
NO_GATES = {"min_tilt_spread_deg": 0.0, "max_focal_std_ratio": 1.0, "max_view_focal_sigma": 1e9}


def _views(rng: np.random.Generator, tilt: tuple[float, float], lenses: list[np.ndarray], noise: float = 0.03) -> list[ViewCorners]:
    """12 views at 400-470 mm, tilted within ``tilt`` deg in random directions; view k taken with ``lenses[k]``."""
    out = []
    for k, Km in enumerate(lenses):
        ax = rng.normal(size=3)
        ax[2] *= 0.3
        rv = ax / np.linalg.norm(ax) * np.radians(rng.uniform(*tilt))
        t = np.array([rng.uniform(-8, 8), rng.uniform(-8, 8), rng.uniform(400, 470)])
        p, _ = cv2.projectPoints(OBJ_C.reshape(-1, 1, 3), rv, t, Km, D)
        out.append(ViewCorners(f"v{k}", p.reshape(-1, 2) + rng.normal(0, noise, (len(OBJ), 2))))
    return out


def _calibrate(views: list[ViewCorners], **limits: float):
    return calibrate_camera(views, OBJ_C, (2048, 2048), fix_k3=True, limits=CameraCalibrationConfig(**limits))


def _focus(pct: float) -> np.ndarray:
    K2 = K.copy()
    K2[0, 0] *= 1 + pct / 100
    K2[1, 1] *= 1 + pct / 100
    return K2


def test_square_on_views_are_refused_naming_the_tilt() -> None:
    views = _views(np.random.default_rng(1), (0.25, 0.5), [K] * 12)
    with pytest.raises(CalibrationRefused) as err:
        _calibrate(views)
    assert err.value.reason == "tilt_too_small"
    assert "largest tilt from square-on 0.4" in err.value.detail and "tilted 15-35 deg" in err.value.detail
    ungated = _calibrate(views, **NO_GATES)
    assert abs(ungated.intrinsics.fx / K[0, 0] - 1) > 0.05  # what the gate protects from: fx 18 % off, "std" 0.01 px


def test_an_uncertain_focal_length_is_refused() -> None:
    # Tilts of 5-10 deg (normal spread above the tilt gate) and 0.3 px noise: RMS 0.42 px passes the 0.5 px limit.
    views = _views(np.random.default_rng(2), (5, 10), [K] * 12, noise=0.3)
    with pytest.raises(CalibrationRefused) as err:
        _calibrate(views)
    assert err.value.reason == "focal_uncertain" and "max_focal_std_ratio" in err.value.detail
    ungated = _calibrate(views, **NO_GATES)
    assert ungated.tilt_spread_deg > 5.0 and ungated.rms_px < 0.5
    assert abs(ungated.intrinsics.fx / K[0, 0] - 1) > 0.002  # > 0.9 mm of depth at 430 mm


@pytest.mark.parametrize(
    ("lenses", "seed"),
    [([K, _focus(1.0)] * 6, 3), ([K] * 6 + [_focus(0.5)] * 6, 4)],
    ids=["alternating-1pct", "refocused-halfway-0.5pct"],
)
def test_views_from_two_focus_settings_are_refused(lenses: list[np.ndarray], seed: int) -> None:
    views = _views(np.random.default_rng(seed), (12, 35), lenses)
    with pytest.raises(CalibrationRefused) as err:
        _calibrate(views)
    assert err.value.reason == "views_disagree"
    assert "focus or zoom" in err.value.detail and "first and second half" in err.value.detail
    ungated = _calibrate(views, **NO_GATES)
    assert ungated.rms_px < 0.1 and not ungated.rejected  # the RMS and view rejection alone let it through
    assert abs(ungated.intrinsics.fx / K[0, 0] - 1) > 0.002  # fx off the truth of the first setting


def test_well_tilted_views_from_one_lens_pass_within_the_gates() -> None:
    res = _calibrate(_views(np.random.default_rng(5), (12, 35), [K] * 12))
    assert abs(res.intrinsics.fx / K[0, 0] - 1) < 5e-4 and abs(res.intrinsics.fy / K[1, 1] - 1) < 5e-4
    assert res.tilt_spread_deg > 10.0 and res.max_tilt_deg > 25.0
    assert 0.0 < res.std["fx"] / res.intrinsics.fx < 2e-4
    assert res.view_focal_sigma < 2.0


def test_a_scatter_of_the_views_too_small_to_matter_is_not_refused() -> None:
    # Sharp corners (0.003 px) and a lens whose views differ by 0.03 % in fx (a model error of a real lens, or
    # focus breathing): many of the views' own sigmas, but 0.6 mm of hand-eye at most; the floor keeps it.
    views = _views(np.random.default_rng(6), (12, 35), [K, _focus(0.03)] * 6, noise=0.003)
    res = _calibrate(views)
    assert res.view_focal_sigma > 3.0 and abs(res.intrinsics.fx / K[0, 0] - 1) < 5e-4
    with pytest.raises(CalibrationRefused) as err:  # without the floor the sigma rule alone refuses it
        _calibrate(views, min_view_focal_spread=0.0)
    assert err.value.reason == "views_disagree"
