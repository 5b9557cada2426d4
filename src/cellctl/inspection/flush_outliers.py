"""Each flush spot checked against the others: a glass or wall reading off its surface (a seal, a reflection).

At each location the step ``glass z - wall z`` carries no robot accuracy error (the two readings are
neighbours), so the steps lie on one plane in (x, y) up to the robot's repeatability. A spot is
judged on its deleted residual, its step against the plane fitted to the other spots, scaled by
``s_(i) * sqrt(1 + x_i^T (X_(i)^T X_(i))^-1 x_i)`` (s_(i): the others' residual scale), with an
absolute floor so that a near-perfect fit does not reject noise. The worst offender beyond the
limit is left out and the rest checked again. A spot the others predict only poorly (a lone far
spot that alone sets a tilt) cannot be checked this way: it is named as unverifiable.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

OUTLIER_K = 4.0  # a deleted residual beyond this many of its predicted sigmas is an outlier
UNVERIFIABLE_GAIN = 2.0  # the others predict the spot with more than this many times one step's scatter
TILT_LEVERAGE = 0.5  # a spot with this leverage in the layout sets a tilt largely alone


@dataclass(frozen=True)
class RejectedSpot:
    """A spot left out: its index in the fit's input, the surface whose reading is off, how far (mm)."""

    index: int
    surface: str
    off_mm: float
    limit_mm: float


@dataclass(frozen=True)
class UnverifiableSpot:
    """A spot the others cannot check: an error below ``detects_above_mm`` there goes unseen (None: none is seen)."""

    index: int
    detects_above_mm: float | None


@dataclass(frozen=True)
class DeletedFit:
    """Per point of a height-plane fit: its deleted residual, the others' scale s_(i), sqrt(1 + x^T (X_(i)^T X_(i))^-1 x)."""

    residual: NDArray[np.float64]
    scale: NDArray[np.float64]
    inflation: NDArray[np.float64]


def _design(xy: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.column_stack([np.ones(len(xy)), xy[:, 0], xy[:, 1]])


def leverages(xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """The hat matrix's diagonal of the plane ``z = a + b x + c y`` over these (x, y) (1: the spot alone fixes its height)."""
    X = _design(np.asarray(xy, dtype=float))
    pinv = np.linalg.pinv(X.T @ X)
    return np.clip(np.einsum("ij,jk,ik->i", X, pinv, X), 0.0, 1.0)


def tilt_setting_spots(xy: NDArray[np.float64]) -> list[int]:
    """The spots of a layout that largely set a tilt alone (leverage above ``TILT_LEVERAGE``)."""
    return [int(i) for i in np.flatnonzero(leverages(xy) > TILT_LEVERAGE)]


def deleted_fit(xy: NDArray[np.float64], z: NDArray[np.float64]) -> DeletedFit:
    """Leave-one-out diagnostics of the plane fit (closed form; inf where the others cannot predict the point)."""
    X = _design(xy)
    n = len(z)
    coef, *_ = np.linalg.lstsq(X, z, rcond=None)
    r = z - X @ coef
    h = leverages(xy)
    free = np.maximum(1.0 - h, 0.0)
    ok = free > 1e-9
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.where(ok, r / np.where(ok, free, 1.0), np.inf)
        sse_i = np.maximum(float(r @ r) - np.where(ok, r**2 / np.where(ok, free, 1.0), 0.0), 0.0)
        s = np.sqrt(sse_i / (n - 4)) if n > 4 else np.full(n, np.inf)
        inflation = np.where(ok, 1.0 / np.sqrt(np.where(ok, free, 1.0)), np.inf)
    return DeletedFit(e, np.where(ok, s, np.inf), inflation)


def _limits(d: DeletedFit, floor_mm: float, k: float) -> NDArray[np.float64]:
    return np.maximum(k * d.scale * d.inflation, floor_mm)


def check_spots(
    glass: NDArray[np.float64], wall: NDArray[np.float64], *, floor_mm: float, k: float = OUTLIER_K
) -> tuple[list[int], list[RejectedSpot], list[UnverifiableSpot]]:
    """The spots kept, those rejected (worst first) and those the others cannot check; rows of ``glass`` and ``wall`` pair up."""
    kept = list(range(len(glass)))
    rejected: list[RejectedSpot] = []
    while len(kept) > 4:
        g, w = glass[kept], wall[kept]
        d = deleted_fit(g[:, :2], g[:, 2] - w[:, 2])
        limit = _limits(d, floor_mm, k)
        # A spot its neighbours cannot predict (one that sets a tilt alone) is never left out: the robot's accuracy
        # differs more between far places than the near spots' scatter says, so noise there looks like an outlier.
        verifiable = np.sqrt(np.maximum(d.inflation**2 - 1.0, 0.0)) <= UNVERIFIABLE_GAIN
        checkable = np.isfinite(d.residual) & np.isfinite(limit) & verifiable
        ratio = np.where(checkable, np.abs(d.residual) / limit, 0.0)
        worst = int(np.argmax(ratio))
        if ratio[worst] <= 1.0:
            break
        rejected.append(RejectedSpot(kept[worst], _surface(g, w, worst), float(d.residual[worst]), float(limit[worst])))
        del kept[worst]
    return kept, rejected, _unverifiable(glass[kept], wall[kept], kept, floor_mm, k)


def _surface(g: NDArray[np.float64], w: NDArray[np.float64], i: int) -> str:
    """Which of the spot's two readings is off its own surface's plane by more."""
    eg = deleted_fit(g[:, :2], g[:, 2]).residual[i]
    ew = deleted_fit(w[:, :2], w[:, 2]).residual[i]
    return "glass" if abs(eg) >= abs(ew) else "wall"


def _unverifiable(
    g: NDArray[np.float64], w: NDArray[np.float64], kept: list[int], floor_mm: float, k: float
) -> list[UnverifiableSpot]:
    if len(kept) < 3:
        return []
    d = deleted_fit(g[:, :2], g[:, 2] - w[:, 2])
    limit = _limits(d, floor_mm, k)
    gain = np.sqrt(np.maximum(d.inflation**2 - 1.0, 0.0))
    return [
        UnverifiableSpot(kept[i], float(limit[i]) if np.isfinite(limit[i]) else None)
        for i in np.flatnonzero(~(gain <= UNVERIFIABLE_GAIN))
    ]
