"""Camera intrinsics: which views calibrate_camera leaves out, against corners projected by OpenCV through a known lens.

Twelve views of the commissioning board (11 x 8 inner corners, 20 mm squares) from about 800 mm, tilted 12-35 deg
about axes spread around the optical axis; the corners are cv2.projectPoints of the true lens, with Gaussian noise
of a chosen size, so which views are bad and what the lens is are known.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cellctl.calibration.board import BoardSpec
from cellctl.calibration.camera import ViewCorners, calibrate_camera
from cellctl.calibration.errors import CalibrationRefused
from cellctl.config.calibration_procedure import CameraCalibrationConfig

K_TRUE = np.array([[5249.574, 0.0, 1014.700], [0.0, 5248.587, 1011.988], [0.0, 0.0, 1.0]])
D_TRUE = np.array([-0.158, -0.0249, -0.0003, 0.0004, 0.0])  # eq. 17, k3 held at 0 as the cell's procedure does
SIZE = (2048, 2048)
OBJ = BoardSpec((11, 8), 20.0).object_points()


def _views(noise_px: list[float], seed: int = 0) -> list[ViewCorners]:
    rng = np.random.default_rng(seed)
    views = []
    centre = OBJ.mean(axis=0)
    for k, sigma in enumerate(noise_px):
        phi = 2.39996 * k
        tilt = np.deg2rad(12.0 + 23.0 * ((0.618034 * k) % 1.0))
        R_P_C = cv2.Rodrigues(np.array([np.cos(phi), np.sin(phi), 0.0]) * tilt)[0]
        R_P_C = R_P_C @ cv2.Rodrigues(np.array([0.0, 0.0, np.deg2rad(25.0 * np.sin(2.4 * k))]))[0]
        o_P = centre + np.append(rng.uniform(-20, 20, 2), 0.0) - 800.0 * R_P_C[:, 2]
        R_C_P = R_P_C.T
        uv, _ = cv2.projectPoints(OBJ.reshape(-1, 1, 3), cv2.Rodrigues(R_C_P)[0], -R_C_P @ o_P, K_TRUE, D_TRUE)
        uv = uv.reshape(-1, 2)
        assert np.all((uv > 20) & (uv < SIZE[0] - 20)), k
        views.append(ViewCorners(f"v{k:02d}", uv + rng.normal(0.0, sigma, uv.shape)))
    return views


def test_a_view_three_times_the_median_but_below_the_floor_is_kept() -> None:
    # Views at 0.01 px and one at 0.06 px: 6 x the median, but a 0.06 px view is a good view (the floor is 0.1 px).
    res = calibrate_camera(_views([0.01] * 11 + [0.06]), OBJ, SIZE, fix_k3=True, limits=CameraCalibrationConfig())
    assert res.rejected == []
    assert len(res.per_view_rms_px) == 12
    assert abs(res.intrinsics.fx / K_TRUE[0, 0] - 1.0) < 1e-3


def test_views_all_above_the_floor_and_alike_are_all_kept() -> None:
    # Every view at 0.15 px: above the 0.1 px floor but none beyond 3 x the median; none is worse than the others.
    res = calibrate_camera(_views([0.15] * 12, seed=1), OBJ, SIZE, fix_k3=True, limits=CameraCalibrationConfig())
    assert res.rejected == []
    assert abs(res.intrinsics.fx / K_TRUE[0, 0] - 1.0) < 2e-3


def test_a_view_far_off_and_above_the_floor_is_rejected_and_the_lens_found_without_it() -> None:
    res = calibrate_camera(_views([0.02] * 11 + [1.5], seed=2), OBJ, SIZE, fix_k3=True, limits=CameraCalibrationConfig())
    assert [n for n, _ in res.rejected] == ["v11"]
    assert abs(res.intrinsics.fx / K_TRUE[0, 0] - 1.0) < 1e-3


def test_views_alike_but_all_too_noisy_are_refused_on_the_rms() -> None:
    # Every view at 0.7 px: none stands out to be rejected, and the whole is over the 0.5 px limit (a board out of focus).
    views = _views([0.7] * 12, seed=3)
    with pytest.raises(CalibrationRefused) as err:
        calibrate_camera(views, OBJ, SIZE, fix_k3=True, limits=CameraCalibrationConfig())
    assert err.value.reason == "rms_too_high"


@pytest.mark.parametrize(("k2", "folds"), [(-100.0, True), (-10.0, False)])
def test_a_lens_whose_model_folds_over_inside_the_image_is_refused(monkeypatch: pytest.MonkeyPatch, k2: float, folds: bool) -> None:
    # OpenCV stands in for a fit whose higher terms ran away beyond the board's reach: its k2 replaced. With k1 = p = k3
    # = 0, r (1 + k2 r^4) turns back at r^4 = -1 / (5 k2), where the distorted radius peaks at 0.8 r. The image's corner
    # lies 0.276 from the axis (normalised): k2 = -100 turns back at 0.211 (peak 0.169, inside the image: no inverse for
    # the corner's pixels), k2 = -10 at 0.376 (peak 0.301, beyond the corner: every pixel has its one inverse).
    real = cv2.calibrateCameraExtended

    def runaway(*args: object, **kwargs: object) -> tuple[object, ...]:
        out = list(real(*args, **kwargs))
        out[2] = np.array([[0.0, k2, 0.0, 0.0, 0.0]])
        return tuple(out)

    monkeypatch.setattr(cv2, "calibrateCameraExtended", runaway)
    corner_r = np.hypot(*(np.array(SIZE) - K_TRUE[:2, 2]) / np.diag(K_TRUE)[:2])
    assert 0.27 < corner_r < 0.28
    assert (0.8 * (-1.0 / (5.0 * k2)) ** 0.25 < corner_r) == folds
    if folds:
        with pytest.raises(CalibrationRefused) as err:
            calibrate_camera(_views([0.1] * 12), OBJ, SIZE, limits=CameraCalibrationConfig())
        assert err.value.reason == "lens_folds_over" and "k2 -100" in err.value.detail
    else:
        try:
            calibrate_camera(_views([0.1] * 12), OBJ, SIZE, limits=CameraCalibrationConfig())
        except CalibrationRefused as err:
            assert err.reason != "lens_folds_over", err
