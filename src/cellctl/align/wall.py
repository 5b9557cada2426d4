"""The car-body wall plane from laser points (paper section 3.1), robust and with its uncertainty."""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.align.errors import AlignmentError, WallFitScatter
from cellctl.geometry.plane import PlaneFit, PlaneFitError, fit_plane

# Above this many spots the robust fit samples triples at random instead of trying them all.
_EXHAUSTIVE_MAX_SPOTS = 30
_RANDOM_TRIPLES = 2000


@dataclass(frozen=True)
class NormalUncertainty:
    """Predicted angular uncertainty of a fitted normal.

    For noise of standard deviation sigma along the normal, a total-least-squares plane's normal
    tilts about the in-plane eigenvector e_k with variance sigma^2 / (lambda_k - lambda_min)
    (k = 1, 2; lambdas from eq. 10), so spots spread wide make a steady normal.

    Attributes:
        sigma_mm: the point noise along the normal that was assumed (mm).
        sigma_source: "residuals" (estimated from the fit) or "prior" (given).
        tilt_sigma_rad: standard deviations of the tilt about the two in-plane axes (rad).
        axes: the two in-plane axes (unit vectors as rows) those tilts turn about... of the fit.
    """

    sigma_mm: float
    sigma_source: str
    tilt_sigma_rad: tuple[float, float]
    axes: NDArray[np.float64]

    @property
    def rms_rad(self) -> float:
        """Expected root-mean-square angle between the fitted and the true normal (rad)."""
        return float(np.hypot(*self.tilt_sigma_rad))

    @property
    def cone95_rad(self) -> float:
        """Half-angle of the cone that holds the true normal with about 95 % probability (rad).

        Uses the larger tilt sigma with the 2-D chi-square 95 % radius, sqrt(5.991).
        """
        return float(np.sqrt(5.991) * max(self.tilt_sigma_rad))


def predict_normal_uncertainty(plane: PlaneFit, sigma_mm: float | None = None) -> NormalUncertainty:
    """Angular uncertainty of ``plane.normal`` from the spot layout and the point noise.

    With ``sigma_mm`` None the noise is estimated from the residuals, sum(r^2) / (n - 3), which
    needs at least 4 points.
    """
    n = plane.residuals.size
    if sigma_mm is None:
        if n <= 3:
            raise AlignmentError(
                "with 3 spots the residuals are zero by construction; give the sensor noise "
                "(sigma_mm) or measure at least 4 spots to estimate the normal's uncertainty"
            )
        sigma = float(np.sqrt(np.sum(plane.residuals**2) / (n - 3)))
        source = "residuals"
    else:
        if not np.isfinite(sigma_mm) or sigma_mm < 0:
            raise AlignmentError(f"sigma_mm must be a finite non-negative number, got {sigma_mm}")
        sigma, source = float(sigma_mm), "prior"
    lam = plane.eigenvalues
    gaps = np.maximum(lam[1:] - lam[0], np.finfo(float).tiny)
    tilt = sigma / np.sqrt(gaps)
    return NormalUncertainty(sigma, source, (float(tilt[0]), float(tilt[1])), plane.eigenvectors[:, 1:].T.copy())


def orient_normal_into_wall(plane: PlaneFit, sensor_points: ArrayLike) -> PlaneFit:
    """The paper's reversal rule: the normal must point into the wall, away from the sensor.

    ``sensor_points`` are positions on the sensor's side (the laser origins). If the normal points
    towards them, the reversed plane is returned.
    """
    S = np.asarray(sensor_points, dtype=float).reshape(-1, 3)
    side = plane.distance(S)
    if np.all(side < 0):
        return plane
    if np.all(side > 0):
        return plane.flipped()
    raise AlignmentError(
        "the laser origins lie on both sides of the fitted plane; the spots do not lie on one wall "
        "seen from one side (check the flange poses and the laser calibration)"
    )


@dataclass(frozen=True)
class RejectedSpot:
    """A laser spot left out of the plane fit, and why."""

    index: int
    residual_mm: float
    reason: str


@dataclass(frozen=True)
class WallPlane:
    """The fitted wall plane with the normal pointing into the wall.

    Attributes:
        plane: the least-squares fit (eq. 2-11) over the inlier spots, oriented into the wall.
        inliers: indices of the spots used.
        rejected: spots left out, with their residual from the final plane and the reason.
        uncertainty: the normal's predicted angular uncertainty.
        rest_shift_mm: from :func:`offset_at_rest`, D at rest less D on the move (mm).
    """

    plane: PlaneFit
    inliers: tuple[int, ...]
    rejected: tuple[RejectedSpot, ...] = field(default=())
    uncertainty: NormalUncertainty | None = None
    rest_shift_mm: float | None = None  # on the move: how far the stops moved the plane's offset (see offset_at_rest)

    @property
    def normal(self) -> NDArray[np.float64]:
        """Unit normal pointing into the wall."""
        return self.plane.normal

    @property
    def offset(self) -> float:
        """D: points p on the wall satisfy normal . p = D (mm)."""
        return self.plane.offset


def fit_wall_plane(
    points: ArrayLike,
    sensor_points: ArrayLike,
    *,
    inlier_threshold_mm: float = 0.5,
    max_rms_mm: float | None = None,
    min_collinearity: float = 1e-3,
    sigma_prior_mm: float | None = None,
) -> WallPlane:
    """Fit the wall plane robustly and orient its normal into the wall.

    Consensus first (every triple of spots when there are few, a random sample when there are
    many; the plane through the triple that agrees with the most spots within
    ``inlier_threshold_mm`` wins, ties going to the smaller residual sum), then the least-squares
    plane of eq. 2-11 over the agreeing spots, repeated until the inlier set no longer changes.
    Of four or more spots, at least four and more than half must agree, and no other group as
    large may agree on another plane: else a bad spot cannot be told from a good one.

    Args:
        points: (N, 3) laser points (eq. 1).
        sensor_points: (N, 3) or (3,) positions on the sensor's side, for the reversal rule.
        inlier_threshold_mm: a spot farther than this from the plane is rejected.
        max_rms_mm: if given, a final fit with a larger RMS residual is refused.
        min_collinearity: smallest lambda_mid/lambda_max accepted (see :func:`fit_plane`).
        sigma_prior_mm: point noise for the uncertainty when it cannot be estimated (3 inliers).

    Raises:
        AlignmentError: too few or degenerate spots, too few inliers, or a fit worse than allowed.
    """
    P = np.asarray(points, dtype=float)
    try:
        first = fit_plane(P, min_collinearity=min_collinearity)  # validates shape, count, finiteness
    except PlaneFitError as err:
        raise AlignmentError(str(err)) from None
    n = P.shape[0]
    inliers, rivals = _consensus(P, inlier_threshold_mm, min_collinearity) if n > 3 else (np.arange(n), [])
    plane = first
    for _ in range(10):
        try:
            plane = fit_plane(P[inliers], min_collinearity=min_collinearity)
        except PlaneFitError as err:
            raise AlignmentError(f"the spots that agree on one plane are degenerate: {err}") from None
        new = np.flatnonzero(np.abs(plane.distance(P)) <= inlier_threshold_mm)
        if new.size < 3 or np.array_equal(new, inliers):
            break
        inliers = new
    if inliers.size < 3:
        raise AlignmentError(
            f"only {inliers.size} of {n} spots agree on one plane within {inlier_threshold_mm} mm; "
            "check for spots off the wall (in the opening, on a seal or a rib)"
        )
    if n > 3:
        _check_majority(P, plane, inliers, rivals, inlier_threshold_mm)
    plane = orient_normal_into_wall(plane, sensor_points)
    rejected = []
    for i in sorted(set(range(n)) - set(inliers.tolist())):
        res = float(plane.distance(P[i]))
        where = "behind" if res > 0 else "in front of"
        rejected.append(
            RejectedSpot(
                i,
                res,
                f"{abs(res):.3f} mm {where} the plane of the other spots (limit {inlier_threshold_mm} mm)",
            )
        )
    if max_rms_mm is not None and plane.rms > max_rms_mm:
        raise WallFitScatter(
            f"wall fit RMS {plane.rms:.3f} mm exceeds the limit {max_rms_mm} mm over {inliers.size} spots; "
            "the wall is not flat where the spots hit it, or a reading is bad"
        )
    if sigma_prior_mm is None and inliers.size <= 3:
        uncertainty = None
    else:
        uncertainty = predict_normal_uncertainty(plane, None if inliers.size > 3 else sigma_prior_mm)
    return WallPlane(plane, tuple(int(i) for i in inliers), tuple(rejected), uncertainty)


def _check_majority(
    P: NDArray[np.float64], plane: PlaneFit, inliers: NDArray[np.intp], rivals: list[NDArray[np.intp]], threshold: float
) -> None:
    """Refuse a plane that is not the clear choice: fewer than 4 or not more than half of the spots agree
    on it, or another group of as many spots agrees on a plane it does not (a member beyond 2 x threshold)."""
    n = P.shape[0]
    residual = plane.distance(P)
    if inliers.size < 4 or 2 * inliers.size <= n:
        off = sorted(set(range(n)) - set(inliers.tolist()))
        spots = ", ".join(f"{i} ({residual[i]:+.2f} mm)" for i in off) or "none"
        raise AlignmentError(
            f"only {inliers.size} of {n} spots agree on one plane within {threshold} mm (need at least 4 and more "
            f"than half, so a bad spot can be told from a good one); off the plane of spots "
            f"{', '.join(map(str, inliers.tolist()))}: {spots}; check for spots off the wall (in the opening, on a "
            "seal or a rib) and for spots without a reading"
        )
    for rival in rivals:
        far = rival[np.abs(residual[rival]) > 2 * threshold]
        if far.size:
            raise AlignmentError(
                f"two groups of {inliers.size} of {n} spots agree on different planes (spots "
                f"{', '.join(map(str, inliers.tolist()))} and {', '.join(map(str, rival.tolist()))}; spot(s) "
                f"{', '.join(f'{i} ({residual[i]:+.2f} mm)' for i in far.tolist())} off the first); the wall cannot be "
                "told from what else the laser hit: check for spots off the wall (in the opening, on a seal or a rib)"
            )


def _consensus(
    P: NDArray[np.float64], threshold: float, min_collinearity: float
) -> tuple[NDArray[np.intp], list[NDArray[np.intp]]]:
    """Indices of the largest set of points lying within ``threshold`` of a plane through 3 of them, and the
    other sets of that size (its rivals)."""
    n = P.shape[0]
    if n <= _EXHAUSTIVE_MAX_SPOTS:
        triples = np.array(list(combinations(range(n), 3)))
    else:
        rng = np.random.default_rng(0)  # deterministic: same spots, same answer
        triples = np.array([rng.choice(n, 3, replace=False) for _ in range(_RANDOM_TRIPLES)])
    a, b, c = P[triples[:, 0]], P[triples[:, 1]], P[triples[:, 2]]
    normals = np.cross(b - a, c - a)
    lengths = np.linalg.norm(normals, axis=1)
    span = np.maximum(np.linalg.norm(b - a, axis=1), np.linalg.norm(c - a, axis=1))
    ok = lengths > np.sqrt(min_collinearity) * span**2
    if not ok.any():
        return np.arange(n), []
    normals = normals[ok] / lengths[ok, None]
    a = a[ok]
    dist = np.abs(P @ normals.T - np.sum(normals * a, axis=1)[None, :])  # (n, triples)
    within = dist <= threshold
    counts = within.sum(axis=0)
    score = np.where(within, dist**2, threshold**2).sum(axis=0)
    best = np.lexsort((score, -counts))[0]
    chosen = np.flatnonzero(within[:, best])
    rivals = {tuple(np.flatnonzero(within[:, k]).tolist()) for k in np.flatnonzero(counts == counts[best])}
    rivals.discard(tuple(chosen.tolist()))
    return chosen, [np.array(r, dtype=np.intp) for r in sorted(rivals)]


def offset_at_rest(
    wall: WallPlane, rest_points: ArrayLike, *, inlier_threshold_mm: float, min_points: int = 10, stops: ArrayLike | None = None
) -> WallPlane:
    """The wall plane with its normal kept and its offset D taken from points read with the flange at rest.

    On the move the arm leaves its reported path by its speed times a direction fixed per path
    direction (the servo's deflection), which shifts the moving readings along the normal and so
    moves D; at rest the deviation is zero. D is the mean of normal . p (eq. 2) over the rest points
    within ``inlier_threshold_mm`` of the moving plane; ``rest_shift_mm`` says how far D moved.
    ``stops`` (M,) names the stop each point was read at: each stop then weighs the same in D, however
    long the flange stood there (the robot's accuracy differs from stop to stop, and teaching reads each once).

    Raises:
        AlignmentError: fewer than ``min_points`` such points.
    """
    P = np.asarray(rest_points, dtype=float).reshape(-1, 3)
    labels = np.zeros(P.shape[0], dtype=int) if stops is None else np.asarray(stops, dtype=int).reshape(-1)
    if labels.shape[0] != P.shape[0]:
        raise AlignmentError(f"{labels.shape[0]} stop labels for {P.shape[0]} readings taken at rest")
    is_near = np.abs(wall.plane.distance(P)) <= inlier_threshold_mm
    near, labels = P[is_near], labels[is_near]
    if near.shape[0] < min_points:
        raise AlignmentError(
            f"only {near.shape[0]} of {P.shape[0]} readings taken at rest lie within {inlier_threshold_mm} mm of the "
            f"wall's plane (need {min_points}): the laser must read the plain wall at each corner of the sweep's path "
            "(on the move, the sweep must stand still at its corners long enough to read)"
        )
    plane = wall.plane
    along = near @ plane.normal
    shift = float(np.mean([along[labels == s].mean() for s in np.unique(labels)])) - plane.offset
    moved = PlaneFit(
        plane.normal, plane.offset + shift, plane.centroid + shift * plane.normal, plane.eigenvalues,
        plane.eigenvectors, plane.residuals - shift,
    )  # fmt: skip
    return WallPlane(moved, wall.inliers, wall.rejected, wall.uncertainty, shift)
