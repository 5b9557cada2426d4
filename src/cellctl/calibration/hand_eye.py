"""Hand-eye calibration (paper section 2, Tsai's method [28], result eq. 18): T_H_C from flange poses and board views.

The board stands still in B while the camera moves around it. For views i, j with flange poses
T_B_H and board poses T_C_P, X = T_H_C solves ``A @ X = X @ B`` with
``A = inv(T_B_H_j) @ T_B_H_i`` (flange motion) and ``B = T_C_P_j @ inv(T_C_P_i)`` (camera motion).

:func:`tsai_lenz` (Tsai and Lenz, 1989): with P = 2 sin(theta/2) axis of A and B,
``skew(P_A + P_B) @ P' = P_B - P_A`` by least squares over all pairs, P_X = 2 P' / sqrt(1 + |P'|^2),
then ``(R_A - I) t_X = R_X t_B - t_A``; the first pass runs from four pre-turns and keeps the best fit, so
none is solved at a half turn, where P' is unbounded; a second pass refines the rest. OpenCV's five methods run
beside it (method passed by keyword, DESIGN.md section 7); :func:`solve_hand_eye` compares them and refuses motion
sets that cannot determine X. The robot poses are the controller's beliefs, so residuals include the robot's error.
A method far (by its median distance) from the others is left out of the agreement check and named
in a warning: OpenCV's Andreff is 58 mm off on an orbit around the board even with exact data,
where the other methods agree to 0.01 mm. :func:`refuse_disagreement` refuses when the chosen one is.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.reproducible import opencv_one_thread
from cellctl.config.calibration_procedure import HAND_EYE_METHODS, HandEyeCalibrationConfig, HandEyeMethod
from cellctl.geometry.pose import Pose, check_pose, invert_pose, make_pose, mean_pose
from cellctl.geometry.rotation import axis_angle_to_matrix, matrix_to_axis_angle, nearest_rotation, rotation_angle_between, skew

F64 = NDArray[np.float64]

_OPENCV_METHOD = {
    "opencv_tsai": cv2.CALIB_HAND_EYE_TSAI,
    "opencv_park": cv2.CALIB_HAND_EYE_PARK,
    "opencv_horaud": cv2.CALIB_HAND_EYE_HORAUD,
    "opencv_andreff": cv2.CALIB_HAND_EYE_ANDREFF,
    "opencv_daniilidis": cv2.CALIB_HAND_EYE_DANIILIDIS,
}


def _modified_rodrigues(R: F64) -> F64:
    """P = 2 sin(theta/2) * axis of rotation R."""
    rv = matrix_to_axis_angle(R)
    theta = float(np.linalg.norm(rv))
    if theta < 1e-15:
        return np.zeros(3)
    return 2.0 * np.sin(theta / 2.0) * rv / theta


def _rotation_from_modified_rodrigues(P: F64) -> F64:
    n2 = float(P @ P)
    R = (1.0 - n2 / 2.0) * np.eye(3) + 0.5 * (np.outer(P, P) + np.sqrt(max(4.0 - n2, 0.0)) * skew(P))
    return nearest_rotation(R)


def _tsai_rotation(A: Sequence[F64], B: Sequence[F64]) -> F64:
    rows = []
    rhs = []
    for Ai, Bi in zip(A, B):
        pa = _modified_rodrigues(Ai[:3, :3])
        pb = _modified_rodrigues(Bi[:3, :3])
        rows.append(skew(pa + pb))
        rhs.append(pb - pa)
    M = np.vstack(rows)
    y = np.concatenate(rhs)
    p_prime, *_ = np.linalg.lstsq(M, y, rcond=None)
    P = 2.0 * p_prime / np.sqrt(1.0 + float(p_prime @ p_prime))
    return _rotation_from_modified_rodrigues(P)


# The identity and turns of 120 deg about x, y and z: a half turn X stays one after a pre-turn only if its axis is
# square to the pre-turn's, and no axis is square to all three.
_PRE_TURNS = (np.eye(3), *(axis_angle_to_matrix(2.0 * np.pi / 3.0 * e) for e in np.eye(3)))


def _pre_turned_rotation(A: Sequence[F64], B: Sequence[F64], R0: F64) -> F64:
    """Tsai's rotation of X solved as X = X' R0: A X' = X' B' with B' = R0 B R0^T, so X' is X turned back by R0."""
    Bp = []
    for b in B:
        m = np.eye(4)
        m[:3, :3] = R0 @ b[:3, :3] @ R0.T
        Bp.append(m)
    return _tsai_rotation(A, Bp) @ R0


def _rotation_misfit(A: Sequence[F64], B: Sequence[F64], R: F64) -> float:
    """Sum over the pairs of |R_A R - R R_B|^2 (Frobenius): 0 for the rotation of X on exact data."""
    return float(sum(np.sum((a[:3, :3] @ R - R @ b[:3, :3]) ** 2) for a, b in zip(A, B)))


def tsai_lenz(A: Sequence[ArrayLike], B: Sequence[ArrayLike]) -> Pose:
    """X with A_k X = X B_k for all motion pairs k (Tsai and Lenz): rotation first, then translation.

    Args:
        A: flange motions (4x4), ``inv(T_B_H_j) @ T_B_H_i``.
        B: camera motions (4x4), ``T_C_P_j @ inv(T_C_P_i)``.
    """
    As = [check_pose(a, "flange motion A") for a in A]
    Bs = [check_pose(b, "camera motion B") for b in B]
    if len(As) != len(Bs) or len(As) < 2:
        raise ValueError(f"Tsai needs at least 2 motion pairs with one A per B, got {len(As)} A and {len(Bs)} B")
    # First pass from each pre-turn, keeping the rotation that fits the pairs best; a second pass for what is left.
    R1 = min((_pre_turned_rotation(As, Bs, R0) for R0 in _PRE_TURNS), key=lambda R: _rotation_misfit(As, Bs, R))
    R = nearest_rotation(_pre_turned_rotation(As, Bs, R1))
    C = np.vstack([a[:3, :3] - np.eye(3) for a in As])
    d = np.concatenate([R @ b[:3, 3] - a[:3, 3] for a, b in zip(As, Bs)])
    t, *_ = np.linalg.lstsq(C, d, rcond=None)
    return make_pose(R, t)


@dataclass(frozen=True)
class MotionPairs:
    """The motion pairs used (i, j) with their A and B, and the pairs left out with why."""

    pairs: list[tuple[int, int]]
    A: list[Pose]
    B: list[Pose]
    angles_rad: F64
    left_out: int


def motion_pairs(T_B_H: Sequence[ArrayLike], T_C_P: Sequence[ArrayLike], *, min_pair_angle_rad: float) -> MotionPairs:
    """All pairs i < j whose flange rotation is at least ``min_pair_angle_rad`` (and not near 180 deg).

    Tsai's axis estimate is ill-conditioned for small relative rotations, so those pairs add noise
    and no information; they are left out (OpenCV's fix for issue 24871 does the same).
    """
    H = [check_pose(h, f"flange pose {k}") for k, h in enumerate(T_B_H)]
    C = [check_pose(c, f"board pose {k}") for k, c in enumerate(T_C_P)]
    pairs: list[tuple[int, int]] = []
    A: list[Pose] = []
    B: list[Pose] = []
    angles: list[float] = []
    left = 0
    for i in range(len(H)):
        for j in range(i + 1, len(H)):
            a = invert_pose(H[j]) @ H[i]
            ang = float(np.linalg.norm(matrix_to_axis_angle(a[:3, :3])))
            if ang < min_pair_angle_rad or ang > np.pi - min_pair_angle_rad:
                left += 1
                continue
            pairs.append((i, j))
            A.append(a)
            B.append(C[j] @ invert_pose(C[i]))
            angles.append(ang)
    return MotionPairs(pairs, A, B, np.asarray(angles), left)


@dataclass(frozen=True)
class MotionDiversity:
    """How well the flange motions constrain X.

    ``axis_spread`` = lambda2 / lambda1 of the weighted scatter of the relative rotation axes
    (0: every rotation about one axis, X's translation along it unobservable; about 0.5 for axes
    spread in a plane; up to 1 for axes spread in 3-D), ``axis_spread_3d`` = lambda3 / lambda1.
    """

    n_views: int
    n_pairs: int
    pairs_left_out: int
    max_pair_angle_deg: float
    median_pair_angle_deg: float
    axis_spread: float
    axis_spread_3d: float


def motion_diversity(T_B_H: Sequence[ArrayLike], *, min_pair_angle_rad: float = np.deg2rad(5.0)) -> MotionDiversity:
    """The spread of the relative rotations between all pairs of flange poses."""
    H = [check_pose(h, f"flange pose {k}") for k, h in enumerate(T_B_H)]
    S = np.zeros((3, 3))
    angles = []
    used = 0
    left = 0
    for i in range(len(H)):
        for j in range(i + 1, len(H)):
            rv = matrix_to_axis_angle((invert_pose(H[j]) @ H[i])[:3, :3])
            ang = float(np.linalg.norm(rv))
            angles.append(ang)
            if ang < min_pair_angle_rad or ang > np.pi - min_pair_angle_rad:
                left += 1
                continue
            k = rv / ang
            w = np.sin(ang / 2.0) ** 2
            S += w * np.outer(k, k)
            used += 1
    lam = np.sort(np.linalg.eigvalsh(S))[::-1] if used else np.zeros(3)
    top = lam[0] if lam[0] > 0 else 1.0
    a = np.degrees(np.asarray(angles)) if angles else np.zeros(1)
    return MotionDiversity(
        n_views=len(H),
        n_pairs=used,
        pairs_left_out=left,
        max_pair_angle_deg=float(a.max()),
        median_pair_angle_deg=float(np.median(a)),
        axis_spread=float(lam[1] / top),
        axis_spread_3d=float(lam[2] / top),
    )


@dataclass(frozen=True)
class HandEyeResidual:
    """How well one X explains the data.

    ``rotation_rms_deg``/``translation_rms_mm``: the AX = XB mismatch ``inv(A X) @ X B`` over the
    pairs. ``board_spread_mm``/``board_spread_deg``: RMS scatter of the board pose in the base
    frame computed from each view (``T_B_H @ X @ T_C_P``), which is constant for a perfect X and
    perfect robot. ``reprojection_rms_px``: the board's corners predicted through the robot
    chain (mean board pose, each flange pose, X) against the detected corners (needs corners).
    """

    rotation_rms_deg: float
    translation_rms_mm: float
    board_spread_mm: float
    board_spread_deg: float
    reprojection_rms_px: float | None


@dataclass(frozen=True)
class HandEyeSolution:
    """One method's X and its residuals."""

    method: HandEyeMethod
    T_H_C: Pose
    residual: HandEyeResidual


@dataclass(frozen=True)
class HandEyeReport:
    """Every method on the same data; ``chosen`` is the one the calibration set takes.

    ``agreement_mm``/``agreement_deg``: for each method, the distance of its X from the chosen
    one. ``warnings``: weak but usable data (few views, little axis spread, an outlier method).
    ``median_mm``/``median_deg``: each method's median distance from the other methods (the lower median).
    ``outliers``: methods whose median distance exceeds the limits, or that failed, with why.
    """

    chosen: HandEyeMethod
    solutions: dict[str, HandEyeSolution]
    diversity: MotionDiversity
    agreement_mm: dict[str, float]
    agreement_deg: dict[str, float]
    warnings: list[str] = field(default_factory=list)
    median_mm: dict[str, float] = field(default_factory=dict)
    median_deg: dict[str, float] = field(default_factory=dict)
    outliers: dict[str, str] = field(default_factory=dict)

    @property
    def T_H_C(self) -> Pose:
        return self.solutions[self.chosen].T_H_C


def evaluate_hand_eye(
    X: ArrayLike,
    T_B_H: Sequence[ArrayLike],
    T_C_P: Sequence[ArrayLike],
    pairs: MotionPairs,
    *,
    object_points: ArrayLike | None = None,
    corners_px: Sequence[ArrayLike] | None = None,
    K: ArrayLike | None = None,
    dist: ArrayLike | None = None,
) -> HandEyeResidual:
    """The residual figures of X on the data (see :class:`HandEyeResidual`)."""
    Xm = check_pose(X, "T_H_C")
    rot = []
    tra = []
    for a, b in zip(pairs.A, pairs.B):
        E = invert_pose(a @ Xm) @ (Xm @ b)
        rot.append(np.linalg.norm(matrix_to_axis_angle(E[:3, :3])))
        tra.append(np.linalg.norm(E[:3, 3]))
    boards = [np.asarray(h, dtype=float) @ Xm @ np.asarray(c, dtype=float) for h, c in zip(T_B_H, T_C_P)]
    mean = mean_pose(np.stack(boards))
    spread_t = np.sqrt(np.mean([np.sum((b[:3, 3] - mean[:3, 3]) ** 2) for b in boards]))
    spread_r = np.sqrt(np.mean([rotation_angle_between(b[:3, :3], mean[:3, :3]) ** 2 for b in boards]))
    reproj = None
    if object_points is not None and corners_px is not None and K is not None and dist is not None:
        obj = np.asarray(object_points, dtype=float)
        sq = []
        for h, uv in zip(T_B_H, corners_px):
            T_C_P_pred = invert_pose(np.asarray(h, dtype=float) @ Xm) @ mean
            rvec, _ = cv2.Rodrigues(T_C_P_pred[:3, :3])
            proj, _ = cv2.projectPoints(obj.reshape(-1, 1, 3), rvec, T_C_P_pred[:3, 3], np.asarray(K, float), np.asarray(dist, float))
            sq.append(np.sum((proj.reshape(-1, 2) - np.asarray(uv, dtype=float)) ** 2, axis=1))
        reproj = float(np.sqrt(np.mean(np.concatenate(sq))))
    return HandEyeResidual(
        rotation_rms_deg=float(np.degrees(np.sqrt(np.mean(np.square(rot))))) if rot else 0.0,
        translation_rms_mm=float(np.sqrt(np.mean(np.square(tra)))) if tra else 0.0,
        board_spread_mm=float(spread_t),
        board_spread_deg=float(np.degrees(spread_r)),
        reprojection_rms_px=reproj,
    )


def opencv_hand_eye(T_B_H: Sequence[ArrayLike], T_C_P: Sequence[ArrayLike], method: HandEyeMethod) -> Pose:
    """X by ``cv2.calibrateHandEye`` with the given method (passed by keyword)."""
    if method not in _OPENCV_METHOD:
        raise ValueError(f"unknown OpenCV hand-eye method {method!r}; choose one of {sorted(_OPENCV_METHOD)}")
    if not hasattr(cv2, "calibrateHandEye"):
        raise RuntimeError(
            "this OpenCV build has no cv2.calibrateHandEye (opencv-python-headless 5.0.0.93 lacks it); "
            "install opencv-python-headless<5"
        )
    Rg = [np.asarray(h, dtype=float)[:3, :3] for h in T_B_H]
    tg = [np.asarray(h, dtype=float)[:3, 3].reshape(3, 1) for h in T_B_H]
    Rc = [np.asarray(c, dtype=float)[:3, :3] for c in T_C_P]
    tc = [np.asarray(c, dtype=float)[:3, 3].reshape(3, 1) for c in T_C_P]
    try:
        with opencv_one_thread():
            R, t = cv2.calibrateHandEye(Rg, tg, Rc, tc, method=_OPENCV_METHOD[method])
    except cv2.error as err:  # e.g. Andreff's "Rotation normalization issue" on an orbit around the board
        why = (err.err or str(err)).strip().splitlines()[-1]
        raise CalibrationRefused("hand_eye", "solver_failed", f"OpenCV's {method} failed on this data ({why})") from None
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float).reshape(3)
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        raise CalibrationRefused("hand_eye", "solver_failed", f"OpenCV's {method} returned NaN for this data")
    return make_pose(nearest_rotation(R), t)


def check_motion(diversity: MotionDiversity, limits: HandEyeCalibrationConfig) -> list[str]:
    """Refuse motion sets that cannot determine X; return warnings for weak but usable ones."""
    d = diversity
    if d.n_views < limits.min_views:
        raise CalibrationRefused(
            "hand_eye", "too_few_views",
            f"{d.n_views} usable view(s); at least {limits.min_views} are needed ({limits.recommended_views} or more "
            "recommended): collect more views with the board found in each",
        )
    if d.max_pair_angle_deg < limits.min_max_pair_angle_deg:
        raise CalibrationRefused(
            "hand_eye", "rotations_too_small",
            f"the flange turned at most {d.max_pair_angle_deg:.1f} deg between views; at least "
            f"{limits.min_max_pair_angle_deg:g} deg is needed: tilt the camera more around the board",
        )
    if d.n_pairs < 2 or d.axis_spread < limits.min_axis_spread:
        raise CalibrationRefused(
            "hand_eye", "one_rotation_axis",
            f"the rotations between views are all about one axis (axis spread {d.axis_spread:.3f}, need at least "
            f"{limits.min_axis_spread:g}); the camera's offset along that axis cannot be found: tilt the camera about "
            "at least two different axes",
        )
    warnings = []
    if d.n_views < limits.recommended_views:
        warnings.append(f"only {d.n_views} views; {limits.recommended_views} or more give a steadier result")
    if d.axis_spread < limits.warn_axis_spread:
        warnings.append(f"rotation axes spread little (axis spread {d.axis_spread:.3f}); add tilts about other axes")
    return warnings


def _checked_poses(T_B_H: Sequence[ArrayLike], T_C_P: Sequence[ArrayLike], names: Sequence[str] | None) -> None:
    """Refuse a flange or board pose that is not a rigid transform, naming its view."""
    for k, (h, c) in enumerate(zip(T_B_H, T_C_P)):
        view = names[k] if names is not None else f"view {k}"
        for pose, what in ((h, "T_B_H"), (c, "board pose")):
            try:
                check_pose(pose, f"{view}.{what}")
            except ValueError as err:
                raise CalibrationRefused(
                    "hand_eye", "bad_pose", f"{err}: correct that pose in the dataset's manifest, or leave the view out"
                ) from None


def _median_distances(solutions: dict[str, HandEyeSolution]) -> tuple[dict[str, float], dict[str, float]]:
    """Each method's median distance (mm, deg) from the other methods' X: the lower median, within which at least half
    of the others lie (of four others, the second nearest: three of five methods that agree are not outvoted by the
    mean of an agreeing and a stray one)."""
    mm: dict[str, float] = {}
    deg: dict[str, float] = {}
    for m, s in solutions.items():
        others = [o.T_H_C for n, o in solutions.items() if n != m]
        X = s.T_H_C
        mm[m] = _lower_median([np.linalg.norm(X[:3, 3] - Y[:3, 3]) for Y in others])
        deg[m] = _lower_median([np.degrees(rotation_angle_between(X[:3, :3], Y[:3, :3])) for Y in others])
    return mm, deg


def _lower_median(values: list[float]) -> float:
    """The middle value, or of an even count the lower of the two middle ones (0 for none)."""
    return float(np.quantile(values, 0.5, method="lower")) if values else 0.0


def refuse_disagreement(rep: HandEyeReport, limits: HandEyeCalibrationConfig) -> tuple[float, float]:
    """The largest distance (mm, deg) of the agreeing methods from the chosen one; refused when the chosen is an outlier."""
    if rep.chosen in rep.outliers:
        agree = [m for m in rep.solutions if m not in rep.outliers]
        raise CalibrationRefused(
            "hand_eye", "methods_disagree",
            f"the methods disagree: the chosen {rep.chosen} is {rep.median_mm[rep.chosen]:.2f} mm and "
            f"{rep.median_deg[rep.chosen]:.3f} deg from the others (median; limits {limits.max_translation_disagreement_mm:g} mm, "
            f"{limits.max_rotation_disagreement_deg:g} deg)"
            + (f"; {', '.join(agree)} agree among themselves: choose one of them (hand_eye.method)" if len(agree) > 1 else
               ": the data is inconsistent (board moved, poses and images mismatched, or poor motion); collect the views again"),
        )
    used = [m for m in rep.solutions if m not in rep.outliers]
    return max(rep.agreement_mm[m] for m in used), max(rep.agreement_deg[m] for m in used)


def _outliers(rep_mm: dict[str, float], rep_deg: dict[str, float], limits: HandEyeCalibrationConfig) -> dict[str, str]:
    """The methods whose median distance from the others exceeds the disagreement limits, with why."""
    lim_mm, lim_deg = limits.max_translation_disagreement_mm, limits.max_rotation_disagreement_deg
    return {
        m: f"{rep_mm[m]:.2f} mm / {rep_deg[m]:.3f} deg from the other methods (median), beyond {lim_mm:g} mm / {lim_deg:g} deg"
        for m in rep_mm
        if rep_mm[m] > lim_mm or rep_deg[m] > lim_deg
    }


def solve_hand_eye(
    T_B_H: Sequence[ArrayLike],
    T_C_P: Sequence[ArrayLike],
    *,
    chosen: HandEyeMethod = "tsai",
    methods: Sequence[HandEyeMethod] = HAND_EYE_METHODS,
    limits: HandEyeCalibrationConfig = HandEyeCalibrationConfig(),
    object_points: ArrayLike | None = None,
    corners_px: Sequence[ArrayLike] | None = None,
    K: ArrayLike | None = None,
    dist: ArrayLike | None = None,
    names: Sequence[str] | None = None,
) -> HandEyeReport:
    """T_H_C by every method in ``methods`` on the same data, refusing degenerate motion sets and bad poses.

    Args:
        T_B_H: flange poses as the robot reported them, one per view.
        T_C_P: the board pose seen by the camera in each view.
        chosen: the method whose X the report gives as the result (default the paper's Tsai).
        methods: the methods to run and compare (``chosen`` is always run).
        object_points, corners_px, K, dist: optional, for the chain reprojection figure.
        names: the views' names, for the refusal of a pose that is not a rigid transform.
    """
    if len(T_B_H) != len(T_C_P):
        raise ValueError(f"{len(T_B_H)} flange poses but {len(T_C_P)} board poses; give one of each per view")
    if chosen not in HAND_EYE_METHODS:
        raise ValueError(f"unknown hand-eye method {chosen!r}; choose one of {list(HAND_EYE_METHODS)}")
    for m in methods:
        if m not in HAND_EYE_METHODS:
            raise ValueError(f"unknown hand-eye method {m!r}; choose one of {list(HAND_EYE_METHODS)}")
    _checked_poses(T_B_H, T_C_P, names)
    diversity = motion_diversity(T_B_H, min_pair_angle_rad=np.deg2rad(limits.min_pair_angle_deg))
    warnings = check_motion(diversity, limits)
    pairs = motion_pairs(T_B_H, T_C_P, min_pair_angle_rad=np.deg2rad(limits.min_pair_angle_deg))
    run = [chosen] + [m for m in methods if m != chosen]
    solutions: dict[str, HandEyeSolution] = {}
    failed: dict[str, str] = {}
    for m in run:
        try:
            X = tsai_lenz(pairs.A, pairs.B) if m == "tsai" else opencv_hand_eye(T_B_H, T_C_P, m)
        except CalibrationRefused as err:
            if m == chosen:
                raise
            failed[m] = err.detail
            continue
        res = evaluate_hand_eye(X, T_B_H, T_C_P, pairs, object_points=object_points, corners_px=corners_px, K=K, dist=dist)
        solutions[m] = HandEyeSolution(m, X, res)
    ref = solutions[chosen].T_H_C
    agree_mm = {m: float(np.linalg.norm(s.T_H_C[:3, 3] - ref[:3, 3])) for m, s in solutions.items()}
    agree_deg = {m: float(np.degrees(rotation_angle_between(s.T_H_C[:3, :3], ref[:3, :3]))) for m, s in solutions.items()}
    med_mm, med_deg = _median_distances(solutions)
    outliers = {**_outliers(med_mm, med_deg, limits), **failed}
    warnings += [f"{m} left out of the comparison between methods: {why}" for m, why in outliers.items() if m != chosen]
    return HandEyeReport(chosen, solutions, diversity, agree_mm, agree_deg, warnings, med_mm, med_deg, outliers)


def board_pose(object_points: ArrayLike, corners_px: ArrayLike, K: ArrayLike, dist: ArrayLike) -> tuple[Pose, float]:
    """The board pose T_C_P from its detected corners (planar PnP, then Levenberg-Marquardt) and its RMS (px)."""
    obj = np.asarray(object_points, dtype=np.float64).reshape(-1, 1, 3)
    img = np.asarray(corners_px, dtype=np.float64).reshape(-1, 1, 2)
    Km = np.asarray(K, dtype=np.float64)
    Dm = np.asarray(dist, dtype=np.float64).reshape(-1, 1)
    with opencv_one_thread():  # the same corners give the same bits (cellctl.calibration.reproducible)
        ok, rvec, tvec = cv2.solvePnP(obj, img, Km, Dm, flags=cv2.SOLVEPNP_IPPE)
        if not ok:
            raise CalibrationRefused("hand_eye", "pose_not_found", "the board pose could not be computed from its corners")
        rvec, tvec = cv2.solvePnPRefineLM(obj, img, Km, Dm, rvec, tvec)
    proj, _ = cv2.projectPoints(obj, rvec, tvec, Km, Dm)
    rms = float(np.sqrt(np.mean(np.sum((proj - img) ** 2, axis=2))))
    R, _ = cv2.Rodrigues(rvec)
    return make_pose(R, tvec.reshape(3)), rms
