"""Camera intrinsics by Zhang's method (paper 2.2): camera matrix A and distortion (eq. 17).

``cv2.calibrateCameraExtended`` on the board's inner corners from several views (found by
cellctl.calibration.board). Bad views are taken out one at a time, worst first, while a view's
reprojection RMS exceeds both ``reject_factor`` times the median of the views and
``reject_floor_px`` (a view with a mis-ordered, blurred or partly hidden board); views whose
board was not found are listed with the detector's reason. The result carries the RMS, every
view's RMS, the standard deviations of the parameters (OpenCV's ``stdDeviationsIntrinsics``),
how much of the image the corners covered, and the board pose in each view. OpenCV's solver runs on one
thread (:mod:`cellctl.calibration.reproducible`): the same views give the same bits.

Refused (CalibrationRefused, with the reason) when fewer than ``min_views`` views are left, when
no view showed the board, when the RMS stays above ``max_rms_px``, when the board's tilt hardly
changed between views (``min_tilt_spread_deg``: parallel views leave the focal length unobservable,
however small the RMS), when the focal length's standard deviation is zero, not finite or above
``max_focal_std_ratio`` of it, and when the views disagree on the focal length (each view's own
fit scatters beyond ``max_view_focal_sigma`` of its uncertainty: focus or zoom changed mid-way).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.reproducible import opencv_one_thread
from cellctl.config.calibration_procedure import CameraCalibrationConfig
from cellctl.geometry.pose import Pose, make_pose
from cellctl.vision.lens import Lens

F64 = NDArray[np.float64]

# Coverage is counted on this grid of image cells.
COVERAGE_GRID = 8


@dataclass(frozen=True)
class ViewCorners:
    """One view: its name and the board's corners (N, 2) in raw pixels, or why it has none."""

    name: str
    corners_px: F64 | None
    reason: str = "ok"


def lens_from_matrix(K: ArrayLike, dist: ArrayLike, image_size: tuple[int, int]) -> Lens:
    """The lens of camera matrix A (px), distortion (k1, k2, p1, p2, k3) (eq. 17) and (width, height) in px."""
    A = np.asarray(K, dtype=float)
    k1, k2, p1, p2, k3 = (float(v) for v in np.asarray(dist, dtype=float).reshape(-1)[:5])
    w, h = int(image_size[0]), int(image_size[1])
    return Lens(float(A[0, 0]), float(A[1, 1]), float(A[0, 2]), float(A[1, 2]), k1, k2, p1, p2, k3, w, h)


@dataclass(frozen=True)
class CameraCalibration:
    """Intrinsics and the figures that say how far to trust them.

    Attributes:
        intrinsics: A, distortion and image size (the lens the corner detector would use).
        rms_px: overall reprojection RMS of the views used.
        per_view_rms_px: each used view's RMS, by name.
        rejected: (view name, reason) of every view left out.
        std: standard deviation of fx, fy, cx, cy (px) and k1, k2, p1, p2, k3.
        coverage: share of the image's 8 x 8 cells that held at least one corner.
        board_poses: T_C_P of each used view, by name.
        flags: the OpenCV flags used.
        tilt_spread_deg, max_tilt_deg: RMS angle of the board's normal from its mean over the views; its largest
            angle from square-on.
        view_focal_sigma: RMS scatter of the single views' fx in units of their own standard deviations.
    """

    intrinsics: Lens
    rms_px: float
    per_view_rms_px: dict[str, float]
    rejected: list[tuple[str, str]]
    std: dict[str, float]
    coverage: float
    board_poses: dict[str, Pose] = field(repr=False)
    flags: int = 0
    tilt_spread_deg: float = float("nan")
    max_tilt_deg: float = float("nan")
    view_focal_sigma: float = float("nan")


def lens_shift_px(K_a: ArrayLike, dist_a: ArrayLike, K_b: ArrayLike, dist_b: ArrayLike, image_size: tuple[int, int]) -> float:
    """The largest distance (px) between the pixels two lenses give the same ray, over 17 x 17 rays spanning the
    (width, height) image of lens a (nan when either lens is not a finite one)."""
    A = np.asarray(K_a, dtype=np.float64)
    u, v = np.meshgrid(np.linspace(0.0, image_size[0] - 1.0, 17), np.linspace(0.0, image_size[1] - 1.0, 17))
    rays = np.column_stack([(u.ravel() - A[0, 2]) / A[0, 0], (v.ravel() - A[1, 2]) / A[1, 1], np.ones(u.size)])
    try:
        pa, pb = (cv2.projectPoints(rays, np.zeros(3), np.zeros(3), np.asarray(K, dtype=np.float64), np.asarray(D, dtype=np.float64))[0]
                  for K, D in ((K_a, dist_a), (K_b, dist_b)))  # fmt: skip
    except cv2.error:
        return float("nan")
    return float(np.max(np.linalg.norm((pa - pb).reshape(-1, 2), axis=1)))


_STD_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


def _coverage(points: Sequence[F64], size: tuple[int, int]) -> float:
    w, h = size
    hit = np.zeros((COVERAGE_GRID, COVERAGE_GRID), dtype=bool)
    for p in points:
        i = np.clip((p[:, 1] / h * COVERAGE_GRID).astype(int), 0, COVERAGE_GRID - 1)
        j = np.clip((p[:, 0] / w * COVERAGE_GRID).astype(int), 0, COVERAGE_GRID - 1)
        hit[i, j] = True
    return float(hit.mean())


def _tilts_deg(rvecs: Sequence[ArrayLike]) -> tuple[float, float]:
    """RMS angle of the board's normal from its mean over the views, and its largest angle from square-on."""
    n = np.array([cv2.Rodrigues(np.asarray(rv, dtype=float))[0][:, 2] for rv in rvecs])
    mean = n.mean(axis=0) / np.linalg.norm(n.mean(axis=0))
    spread = np.arccos(np.clip(n @ mean, -1.0, 1.0))
    tilt = np.arccos(np.clip(np.abs(n[:, 2]), 0.0, 1.0))
    return float(np.degrees(np.sqrt(np.mean(spread**2)))), float(np.degrees(tilt.max()))


def _refuse_unobservable(K: F64, std: F64, tilt: tuple[float, float], limits: CameraCalibrationConfig) -> None:
    """Refuse views too alike in tilt, and a focal length or principal point OpenCV cannot pin down."""
    spread, largest = tilt
    if spread < limits.min_tilt_spread_deg:
        raise CalibrationRefused(
            "camera", "tilt_too_small",
            f"the board's tilt hardly changed between the views (its normal spread {spread:.2f} deg, need at least "
            f"{limits.min_tilt_spread_deg:g} deg; largest tilt from square-on {largest:.2f} deg), so the focal length "
            "cannot be told from the distance: add views tilted 15-35 deg in different directions, about two axes",
        )
    names = ("fx", "fy", "cx", "cy")
    bad = [n for n, s in zip(names, std[:4]) if not np.isfinite(s) or s <= 0.0]
    ratio = max(float(std[0] / K[0, 0]), float(std[1] / K[1, 1])) if not bad else float("nan")
    if bad or ratio > limits.max_focal_std_ratio:
        what = f"the standard deviation of {', '.join(bad)} is zero or not finite" if bad else (
            f"fx and fy are uncertain by up to {ratio:.1e} of their value (std fx {std[0]:.2f} px, fy {std[1]:.2f} px; "
            f"limit max_focal_std_ratio {limits.max_focal_std_ratio:g})")
        raise CalibrationRefused(
            "camera", "focal_uncertain",
            f"{what}: the views do not determine the lens (largest tilt {largest:.1f} deg); add views tilted 15-35 deg "
            "about two axes, at different distances, with the board reaching the image's corners",
        )


_SINGLE_VIEW_FLAGS = (
    cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_PRINCIPAL_POINT | cv2.CALIB_FIX_ASPECT_RATIO
    | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_FIX_TANGENT_DIST
)  # fmt: skip


def _refuse_folding(lens: Lens) -> None:
    """Refuse a lens whose distortion model folds over inside its image (eq. 17 has no unique inverse there): the
    corner finder could not undistort the pixels beyond the fold. Checked on 33 x 33 pixels spanning the image."""
    u, v = np.meshgrid(np.linspace(0.0, lens.width_px - 1.0, 33), np.linspace(0.0, lens.height_px - 1.0, 33))
    try:
        lens.undistort(np.column_stack([u.ravel(), v.ravel()]))
    except ValueError as err:
        raise CalibrationRefused(
            "camera", "lens_folds_over",
            f"the distortion (k1 {lens.k1:.4g}, k2 {lens.k2:.4g}, k3 {lens.k3:.4g}) folds over inside the image ({err}): "
            "the board's corners did not reach far enough into the image's corners for the higher terms; add views with "
            "the board in the corners of the image, or hold k3 at 0 (calibration.camera.fix_k3 = true)",
        ) from None


def view_focal_lengths(op: F64, ip: Sequence[F64], size: tuple[int, int], K: F64, D: F64) -> tuple[F64, F64]:
    """Each view's own fx (the other intrinsics held at K, D) and its standard deviation (px)."""
    f, s = [], []
    for pts in ip:
        with opencv_one_thread():
            _, Kv, _, _, _, std, _, _ = cv2.calibrateCameraExtended(
                [op], [pts], size, K.copy(), D.copy(), flags=_SINGLE_VIEW_FLAGS,
                criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12),
            )
        f.append(float(Kv[0, 0]))
        s.append(float(np.asarray(std, dtype=float).reshape(-1)[1]) * float(K[0, 0] / K[1, 1]))  # fy is the free one
    return np.asarray(f), np.asarray(s)


def _refuse_mixed_views(names: Sequence[str], f: F64, s: F64, limits: CameraCalibrationConfig) -> float:
    """The views' fx scatter in their own sigmas; refused beyond ``max_view_focal_sigma`` (focus or zoom changed)."""
    ok = np.isfinite(f) & np.isfinite(s) & (s > 0.0)
    if ok.sum() < 3:
        return float("nan")
    w = 1.0 / s[ok] ** 2
    mean = np.sum(w * f[ok]) / np.sum(w)
    chi = float(np.sqrt(np.sum(w * (f[ok] - mean) ** 2) / (ok.sum() - 1)))
    spread = float(np.sqrt(np.sum(w * (f[ok] - mean) ** 2) / np.sum(w)) / mean)
    if chi <= limits.max_view_focal_sigma or spread <= limits.min_view_focal_spread:
        return chi
    half = len(f) // 2
    means = [float(np.average(f[sl][ok[sl]], weights=1.0 / s[sl][ok[sl]] ** 2)) if ok[sl].any() else float("nan")
             for sl in (slice(0, half), slice(half, None))]  # fmt: skip
    lo, hi = int(np.nanargmin(np.where(ok, f, np.nan))), int(np.nanargmax(np.where(ok, f, np.nan)))
    raise CalibrationRefused(
        "camera", "views_disagree",
        f"the views disagree on the focal length: single views give fx from {f[lo]:.1f} px ({names[lo]}) to "
        f"{f[hi]:.1f} px ({names[hi]}), the first and second half of the collection {means[0]:.1f} and {means[1]:.1f} px; "
        f"they scatter {chi:.1f} times their own uncertainty and {100 * spread:.2f} % of fx (limits max_view_focal_sigma "
        f"{limits.max_view_focal_sigma:g}, min_view_focal_spread {limits.min_view_focal_spread:g}): "
        "was the focus or zoom changed during collection? collect again with the lens locked",
    )


def calibrate_camera(
    views: Sequence[ViewCorners],
    object_points: ArrayLike,
    image_size: tuple[int, int],
    *,
    fix_k3: bool = False,
    limits: CameraCalibrationConfig = CameraCalibrationConfig(),
) -> CameraCalibration:
    """Zhang's calibration on the views whose board was found; bad views rejected.

    Args:
        views: every view collected, with its corners or the reason it has none.
        object_points: the board's inner corners (N, 3) in the board frame (mm).
        image_size: (width, height) in pixels.
        fix_k3: keep k3 at 0 (for a lens whose r^6 term the views cannot resolve).
        limits: the refusal thresholds (``min_views``, ``max_rms_px``, ``reject_factor``, ``reject_floor_px``,
            ``min_tilt_spread_deg``, ``max_focal_std_ratio``, ``max_view_focal_sigma``); the other fields are the
            procedure's and not read here.
    """
    obj = np.asarray(object_points, dtype=np.float64)
    if obj.ndim != 2 or obj.shape[1] != 3:
        raise ValueError(f"object_points must have shape (N, 3), got {obj.shape}")
    w, h = int(image_size[0]), int(image_size[1])
    if w <= 0 or h <= 0:
        raise ValueError(f"image_size must be positive (width, height), got {image_size!r}")
    rejected: list[tuple[str, str]] = []
    used: list[ViewCorners] = []
    for v in views:
        if v.corners_px is None:
            rejected.append((v.name, f"board not found: {v.reason}"))
        elif np.shape(v.corners_px) != (len(obj), 2):
            rejected.append((v.name, f"{len(v.corners_px)} corners for a board of {len(obj)}"))
        else:
            used.append(v)
    if not used:
        raise CalibrationRefused(
            "camera", "board_not_found",
            f"the board was not found in any of the {len(views)} views"
            + (f" (first reason: {rejected[0][1]})" if rejected else "")
            + "; check the board size in the configuration, the lighting and that the board is in view",
        )
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    while True:
        if len(used) < limits.min_views:
            raise CalibrationRefused(
                "camera", "too_few_views",
                f"{len(used)} usable view(s) of {len(views)}; at least {limits.min_views} are needed"
                + (f" (left out: {'; '.join(f'{n}: {r}' for n, r in rejected[:4])})" if rejected else "")
                + ": collect more views of the board, tilted in different directions",
            )
        op = [obj.astype(np.float32).reshape(-1, 1, 3)] * len(used)
        ip = [np.asarray(v.corners_px, dtype=np.float32).reshape(-1, 1, 2) for v in used]
        with opencv_one_thread():  # on the pool, the same views gave other bits from run to run
            rms, K, D, rvecs, tvecs, std_in, _, per_view = cv2.calibrateCameraExtended(
                op, ip, (w, h), None, None, flags=flags,
                criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12),
            )
        per = np.asarray(per_view, dtype=float).reshape(-1)
        worst = int(np.argmax(per))
        median = float(np.median(per))
        if per[worst] > limits.reject_factor * median and per[worst] > limits.reject_floor_px:
            rejected.append(
                (used[worst].name, f"reprojection {per[worst]:.3f} px, {per[worst] / median:.1f} x the median {median:.3f} px")
            )
            used = used[:worst] + used[worst + 1 :]
            continue
        break
    if rms > limits.max_rms_px:
        raise CalibrationRefused(
            "camera", "rms_too_high",
            f"reprojection RMS {rms:.3f} px exceeds {limits.max_rms_px:g} px: check the board's flatness and printed "
            "square size, focus and that the camera and lens were fixed during the views",
        )
    lens = lens_from_matrix(K, D, (w, h))
    _refuse_folding(lens)
    std = np.asarray(std_in, dtype=float).reshape(-1)
    tilt = _tilts_deg(rvecs)
    _refuse_unobservable(np.asarray(K, dtype=float), std, tilt, limits)
    f, s = view_focal_lengths(op[0], ip, (w, h), np.asarray(K, dtype=float), np.asarray(D, dtype=float))
    chi = _refuse_mixed_views([v.name for v in used], f, s, limits)
    poses = {}
    for v, rv, tv in zip(used, rvecs, tvecs):
        R, _ = cv2.Rodrigues(rv)
        poses[v.name] = make_pose(R, np.asarray(tv, dtype=float).reshape(3))
    return CameraCalibration(
        intrinsics=lens,
        rms_px=float(rms),
        per_view_rms_px={v.name: float(p) for v, p in zip(used, per)},
        rejected=rejected,
        std={n: float(s) for n, s in zip(_STD_NAMES, std[: len(_STD_NAMES)])},
        coverage=_coverage([np.asarray(v.corners_px, dtype=float) for v in used], (w, h)),
        board_poses=poses,
        flags=flags,
        tilt_spread_deg=tilt[0],
        max_tilt_deg=tilt[1],
        view_focal_sigma=chi,
    )
