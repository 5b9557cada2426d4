"""The laser's origin r and unit direction l in the flange frame, from plane constraints (paper 2.2).

The robot points the laser at one flat reference surface from many flange poses (R_i, t_i) and
records the distances d_i. Every laser point (eq. 1) lies on the plane n . p = D:

    n . (R_i (r + d_i l) + t_i) - D = 0.

r, l (with |l| = 1) and, by default, the plane (n, D) are found by nonlinear least squares
(Levenberg-Marquardt) on these residuals. The unit vectors are parametrised on their spheres
(two tangent coordinates around the current estimate), so |l| = |n| = 1 holds exactly and the
covariance has no gauge direction.

Why the plane is unknown by default: a "known" plane has to be measured by something else, in
the cell by touching it with a robot-held pointer, which brings the robot's absolute-accuracy
error (up to 0.5 mm here) straight into r; estimating the plane with r and l uses only the
distances and the robot's reported poses, the same quantities the alignment step uses later.
The price is that r's component along the mean beam direction and the plane's offset D are told
apart only through the tilts: r is observable when the plane normal, seen from the flange
(m_i = R_i^T n), is spread over a cap of directions, not a circle or a point. The data are
therefore refused when the normal's spread about either axis across the beam is below
``min_direction_spread_deg`` ("plane seen from too few directions"), and the standard deviations
of every parameter are reported from the covariance sigma^2 (J^T J)^-1. A known plane
(``plane=(n, D)``) can be given instead when it has been measured independently.

Two nuisance models keep systematic errors out of r and l (both optional, both on in the cell's
procedure):

- ``groups``: poses taken with the arm standing still and only the wrist turning (the planner
  turns the flange about the wrist centre) share a plane offset of their own. The robot's
  position error depends on where the arm is, so within a group it is one constant, and that
  constant goes into the group's offset instead of into r.
- ``linearity_terms``: the sensor's linearity deviation (+-0.02 % of full scale on the LK-G500,
  a smooth curve over the range) is modelled as Legendre polynomials of degree 2 and up in the
  normalised distance (degrees 0 and 1 are r along l and the sensor's scale, not linearity).

Measured in the twin over 20 seeds with the default plan (480 poses, ``cellctl bench calibration
--seeds 20``): with exact robot poses r is within 0.009 mm and l within 0.001 deg of the truth;
with the uncalibrated robot's reported poses (0.5 mm / 0.015 deg accuracy field, 0.1 mm / 0.005 deg
repeatability) r is within 0.17 mm (median 0.06) and l within 0.016 deg (median 0.006). The
robot's repeatability alone gives l within 0.014 deg, which the reported standard deviations
(about 0.007 deg per axis) cover; the accuracy field alone gives 0.009 deg, which they do not:
its orientation part, one small rotation of the flange per arm stand, moves the laser point
differently at every turn of the wrist, and no nuisance term models it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from cellctl.calibration.errors import CalibrationRefused
from cellctl.config.calibration_procedure import LASER_MIN_POSES, LaserCalibrationConfig
from cellctl.geometry.plane import PlaneFitError, fit_plane

F64 = NDArray[np.float64]

_ALTERNATIONS = 8


@dataclass(frozen=True)
class LaserCalibration:
    """r and l with their uncertainty, the plane, and the fit's quality figures.

    Attributes:
        r: laser origin in the flange frame (mm).
        l: unit laser direction in the flange frame.
        r_sigma_mm: standard deviation of each component of r.
        l_sigma_deg: standard deviation of l's direction about the two axes across it.
        plane_normal, plane_offsets_mm: the reference plane n . p = D in the base frame (one
            offset per group of poses).
        plane_known: whether the plane was given (True) or estimated (False).
        rms_mm, max_residual_mm: distances of the laser points from the plane.
        direction_spread_deg: spread (1 sigma) of the plane normal seen from the flange, about
            the two axes across the beam.
        n_poses: poses used.
        residuals_mm: the residual of each pose.
        plane_sigma_deg: standard deviation of the estimated plane normal (None if known).
        linearity_coefficients_mm: the fitted Legendre coefficients of the sensor's linearity.
    """

    r: F64
    l: F64  # noqa: E741
    r_sigma_mm: F64
    l_sigma_deg: F64
    plane_normal: F64
    plane_offsets_mm: F64
    plane_known: bool
    plane_sigma_deg: float | None
    rms_mm: float
    max_residual_mm: float
    direction_spread_deg: tuple[float, float]
    n_poses: int
    residuals_mm: F64
    linearity_coefficients_mm: F64


def _tangent_basis(v: F64) -> tuple[F64, F64]:
    a = np.eye(3)[int(np.argmin(np.abs(v)))]
    e1 = np.cross(v, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(v, e1)


def _on_sphere(v0: F64, basis: tuple[F64, F64], ab: F64) -> F64:
    w = v0 + ab[0] * basis[0] + ab[1] * basis[1]
    return w / np.linalg.norm(w)


def _points(R: F64, t: F64, d: F64, r: F64, l: F64) -> F64:  # noqa: E741
    return np.einsum("nij,nj->ni", R, r[None, :] + d[:, None] * l[None, :]) + t


def direction_spread_deg(R: F64, normal: F64) -> tuple[float, float]:
    """1-sigma spread (deg) of the plane normal seen from the flange, about the two axes across it."""
    m = np.einsum("nji,j->ni", R, normal)  # R_i^T n
    mean = m.mean(axis=0)
    mean /= np.linalg.norm(mean)
    e1, e2 = _tangent_basis(mean)
    proj = np.column_stack([m @ e1, m @ e2])
    cov = np.cov(proj.T) if len(m) > 1 else np.zeros((2, 2))
    lam = np.sort(np.clip(np.linalg.eigvalsh(cov), 0.0, None))
    return float(np.degrees(np.sqrt(lam[0]))), float(np.degrees(np.sqrt(lam[1])))


def _linear_r_l(R: F64, t: F64, d: F64, n: F64, D: F64, g: NDArray[np.intp], free_D: bool) -> tuple[F64, F64, F64]:
    """r, the unnormalised l and (if free) the offsets with the normal fixed:
    n^T R_i r + d_i n^T R_i w - D_g(i) = -n^T t_i."""
    m = np.einsum("nji,j->ni", R, n)
    M = np.hstack([m, d[:, None] * m])
    y = -t @ n
    if free_D:
        M = np.hstack([M, -np.eye(int(g.max()) + 1)[g]])
    else:
        y = y + D[g]
    sol, *_ = np.linalg.lstsq(M, y, rcond=None)
    return sol[:3], sol[3:6], (sol[6:] if free_D else D)


def calibrate_laser(
    T_B_H: Sequence[ArrayLike] | ArrayLike,
    distances_mm: ArrayLike,
    r_nominal: ArrayLike,
    l_nominal: ArrayLike,
    *,
    groups: ArrayLike | None = None,
    plane: tuple[ArrayLike, float] | None = None,
    linearity_terms: int = 0,
    distance_range_mm: tuple[float, float] | None = None,
    limits: LaserCalibrationConfig = LaserCalibrationConfig(min_poses=LASER_MIN_POSES),
) -> LaserCalibration:
    """r and l from readings of one flat surface (paper 2.2), by Levenberg-Marquardt.

    Args:
        T_B_H: (N, 4, 4) flange poses the robot reported at the readings.
        distances_mm: (N,) laser distances.
        r_nominal, l_nominal: the CAD mounting, the starting point of the fit (l within about
            20 deg of the truth, r within a few tens of mm is enough).
        groups: optional (N,) group index per reading: poses taken with the arm in one place
            (only the wrist turning, see cellctl.calibration.poses.plan_laser_poses). Each group
            gets its own plane offset, which takes up the arm's position error common to the group.
        plane: a known plane (unit normal n, offset D with n . p = D in B); default estimated.
        linearity_terms: how many Legendre terms (degree 2 and up) model the sensor's linearity.
        distance_range_mm: the sensor's measuring range, which the Legendre terms are normalised
            to (default: the range of the distances given).
        limits: the refusal thresholds (``min_poses`` to ``max_l_sigma_deg``); the other fields
            are the procedure's and not read here.

    Raises CalibrationRefused when there are too few poses, the plane is seen from too few
    directions, or the fit's residuals or uncertainties exceed the limits.
    """
    H = np.asarray(T_B_H, dtype=float)
    d = np.asarray(distances_mm, dtype=float).reshape(-1)
    if H.ndim != 3 or H.shape[1:] != (4, 4):
        raise ValueError(f"flange poses must have shape (N, 4, 4), got {H.shape}")
    if len(H) != len(d):
        raise ValueError(f"{len(H)} flange poses but {len(d)} distances; give one pose per reading")
    if not (np.all(np.isfinite(H)) and np.all(np.isfinite(d))):
        raise ValueError("flange poses and distances must be finite numbers")
    known = plane is not None
    if groups is None:
        g = np.zeros(len(d), dtype=np.intp)
    else:
        if known:
            raise ValueError("a known plane has one offset; give groups only when the plane is estimated")
        raw = np.asarray(groups).reshape(-1)
        if len(raw) != len(d):
            raise ValueError(f"{len(raw)} group indices for {len(d)} readings")
        _, g = np.unique(raw, return_inverse=True)
        g = g.astype(np.intp)
    n_groups = int(g.max()) + 1 if len(g) else 0
    if len(H) < limits.min_poses:
        raise CalibrationRefused(
            "laser", "too_few_poses",
            f"{len(H)} readings; at least {limits.min_poses} are needed: measure the plane from more flange poses",
        )
    R, t = H[:, :3, :3], H[:, :3, 3]
    lo, hi = distance_range_mm if distance_range_mm is not None else (float(d.min()), float(d.max()))
    u = np.clip((2.0 * d - (lo + hi)) / max(hi - lo, 1e-9), -1.0, 1.0)
    basis = np.column_stack([np.polynomial.legendre.legval(u, np.eye(linearity_terms + 2)[k]) for k in range(2, linearity_terms + 2)]) if linearity_terms else np.zeros((len(d), 0))
    nc = basis.shape[1]
    r = np.asarray(r_nominal, dtype=float).copy()
    l = np.asarray(l_nominal, dtype=float) / np.linalg.norm(l_nominal)  # noqa: E741
    if known:
        n = np.asarray(plane[0], dtype=float)  # type: ignore[index]
        n = n / np.linalg.norm(n)
        D = np.array([float(plane[1])])  # type: ignore[index]
    else:
        try:
            fit = fit_plane(_points(R, t, d, r, l), min_collinearity=1e-3)
        except PlaneFitError as err:
            raise CalibrationRefused(
                "laser", "spots_not_spread",
                f"the laser spots do not span the plane ({err}); aim at spots spread in two directions over the surface",
            ) from None
        n = fit.normal
        D = np.full(n_groups, fit.offset)
    spread = direction_spread_deg(R, n)
    if spread[0] < limits.min_direction_spread_deg:
        raise CalibrationRefused(
            "laser", "plane_too_few_directions",
            f"the plane was seen from too few directions: its normal, seen from the flange, spread only "
            f"{spread[0]:.2f} deg about one axis across the beam (and {spread[1]:.2f} deg about the other); "
            f"at least {limits.min_direction_spread_deg:g} deg about both is needed: tilt the sensor about two axes",
        )
    # Starting point: alternate the linear solve for (r, l) and the plane fit, with one offset
    # (per-group offsets would let the scale of the unnormalised l drift in the linear step).
    one = np.zeros(len(d), dtype=np.intp)
    D1 = D[:1].copy()
    for _ in range(_ALTERNATIONS):
        r, w, D1 = _linear_r_l(R, t, d, n, D1, one, False)
        l = w / np.linalg.norm(w)  # noqa: E741
        if known:
            break
        fit = fit_plane(_points(R, t, d, r, l))
        n = fit.normal if fit.normal @ n > 0 else -fit.normal
        D1 = np.array([float(n @ fit.centroid)])
    if not known:
        D = np.full(n_groups, D1[0])

    def unpack(x: F64, l0: F64, lb: tuple[F64, F64], n0: F64, nb: tuple[F64, F64]) -> tuple[F64, F64, F64, F64, F64]:
        rr = x[:3]
        ll = _on_sphere(l0, lb, x[3:5])
        cc = x[5 : 5 + nc]
        if known:
            return rr, ll, n0, D, cc
        return rr, ll, _on_sphere(n0, nb, x[5 + nc : 7 + nc]), x[7 + nc :], cc

    def solve(r0: F64, l0: F64, n0: F64, D0: F64, c0: F64) -> tuple[F64, F64, F64, F64, F64, F64, F64]:
        lb, nb = _tangent_basis(l0), _tangent_basis(n0)
        x0 = np.concatenate([r0, [0.0, 0.0], c0] + ([] if known else [[0.0, 0.0], D0]))

        def residuals(x: F64) -> F64:
            rr, ll, nn, DD, cc = unpack(x, l0, lb, n0, nb)
            return _points(R, t, d - basis @ cc, rr, ll) @ nn - DD[g]

        sol = least_squares(residuals, x0, method="lm", x_scale="jac", xtol=1e-14, ftol=1e-14, gtol=1e-14)
        rr, ll, nn, DD, cc = unpack(sol.x, l0, lb, n0, nb)
        return rr, ll, nn, DD, cc, sol.fun, sol.jac

    c = np.zeros(nc)
    r, l, n, D, c, _, _ = solve(r, l, n, D, c)
    # Re-centre the sphere parametrisations on the solution and take the Jacobian there.
    r, l, n, D, c, res, J = solve(r, l, n, D, c)
    m, p = len(res), J.shape[1]
    dof = m - p
    if dof <= 0:
        raise CalibrationRefused("laser", "too_few_poses", f"{m} readings for {p} unknowns")
    s2 = float(res @ res) / dof
    JTJ = J.T @ J
    if np.linalg.cond(JTJ) > 1e14:
        raise CalibrationRefused(
            "laser", "plane_too_few_directions",
            "the readings do not determine r and l (the normal equations are singular): tilt the sensor about two axes "
            "and vary the stand-off",
        )
    cov = s2 * np.linalg.inv(JTJ)
    sig = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    rms = float(np.sqrt(np.mean(res**2)))
    result = LaserCalibration(
        r=r,
        l=l,
        r_sigma_mm=sig[:3],
        l_sigma_deg=np.degrees(sig[3:5]),
        plane_normal=n,
        plane_offsets_mm=D.copy(),
        plane_known=known,
        plane_sigma_deg=None if known else float(np.degrees(np.hypot(sig[5 + nc], sig[6 + nc]))),
        rms_mm=rms,
        max_residual_mm=float(np.max(np.abs(res))),
        direction_spread_deg=spread,
        n_poses=m,
        residuals_mm=res,
        linearity_coefficients_mm=c.copy(),
    )
    if rms > limits.max_rms_mm:
        raise CalibrationRefused(
            "laser", "residual_too_high",
            f"the laser points lie {rms:.3f} mm RMS from the plane (limit {limits.max_rms_mm:g} mm): is the surface flat, "
            "clean and within range at every pose, and did the robot stand still at each reading?",
        )
    if np.max(result.r_sigma_mm) > limits.max_r_sigma_mm or np.max(result.l_sigma_deg) > limits.max_l_sigma_deg:
        raise CalibrationRefused(
            "laser", "uncertain",
            f"r is known only to {np.max(result.r_sigma_mm):.3f} mm and l to {np.max(result.l_sigma_deg):.4f} deg (1 sigma; "
            f"limits {limits.max_r_sigma_mm:g} mm, {limits.max_l_sigma_deg:g} deg): add poses with larger tilts about "
            "both axes across the beam",
        )
    return result
