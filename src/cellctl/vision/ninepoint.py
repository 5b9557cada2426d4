"""The nine-point map from image pixels to workpiece millimetres (paper section 4.3, step 1).

Nine (or more) points whose workpiece coordinates are known are found in the undistorted image;
an affine map (x, y) = M @ (u, v, 1) is fitted by least squares and its residuals at the points
are reported. The nine-point plate's dots can be found with :func:`find_dot_grid`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.vision.lens import Lens

F64 = NDArray[np.float64]


class NinePointError(ValueError):
    """The nine-point data cannot give a map; the message says why and what to do."""


@dataclass(frozen=True)
class AffineMap:
    """(x, y) in mm = ``matrix`` @ (u, v, 1) for undistorted pixel positions (u, v).

    ``residuals_mm`` are the distances between each point's known position and where the map
    puts it; ``rms_mm`` and ``max_mm`` summarise them.
    """

    matrix: F64
    residuals_mm: F64
    rms_mm: float
    max_mm: float

    @property
    def linear(self) -> F64:
        """The 2 x 2 part: mm per px along u and v (a pixel displacement's image in mm)."""
        return self.matrix[:, :2]

    @property
    def mm_per_px(self) -> float:
        """Mean scale: the square root of the area ratio."""
        return float(np.sqrt(abs(np.linalg.det(self.linear))))

    @property
    def rotation_rad(self) -> float:
        """Angle of the image's u axis in the workpiece frame (the rotation of the map's closest similarity)."""
        L = self.linear
        return float(np.arctan2(L[1, 0] - L[0, 1], L[0, 0] + L[1, 1]))

    def apply(self, pixels: ArrayLike) -> F64:
        """Workpiece coordinates (N, 2) in mm of undistorted pixel positions (N, 2)."""
        P = np.atleast_2d(np.asarray(pixels, dtype=float))
        return P @ self.linear.T + self.matrix[:, 2]

    def check(self, max_rms_mm: float) -> None:
        """Raise NinePointError when the residual RMS exceeds ``max_rms_mm``."""
        if self.rms_mm > max_rms_mm:
            worst = int(np.argmax(self.residuals_mm))
            raise NinePointError(
                f"the nine-point map fits its points to {self.rms_mm:.4f} mm RMS (point {worst + 1} is "
                f"{self.max_mm:.4f} mm off), above the limit {max_rms_mm:g} mm: check the point order "
                "and the known coordinates, and that the target lies flat in the wall plane"
            )


def fit_affine_map(pixels: ArrayLike, points_mm: ArrayLike) -> AffineMap:
    """Least-squares affine map from undistorted pixels (N, 2) to workpiece mm (N, 2), N >= 3."""
    P = np.asarray(pixels, dtype=float)
    X = np.asarray(points_mm, dtype=float)
    if P.ndim != 2 or P.shape[1] != 2 or X.shape != P.shape:
        raise NinePointError(f"pixels and points_mm must both have shape (N, 2), got {P.shape} and {X.shape}")
    if len(P) < 3:
        raise NinePointError(f"an affine map needs at least 3 point pairs, got {len(P)}")
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(X))):
        raise NinePointError("pixels and points_mm must be finite numbers")
    for what, Q in (("pixels", P), ("points_mm", X)):
        sv = np.linalg.svd(Q - Q.mean(axis=0), compute_uv=False)
        if sv[1] < 1e-6 * max(sv[0], 1e-12) or sv[0] == 0.0:
            raise NinePointError(f"the {what} lie on a line: the map needs points spread in two directions")
    A = np.column_stack([P, np.ones(len(P))])
    sol, *_ = np.linalg.lstsq(A, X, rcond=None)
    M = sol.T
    res = np.linalg.norm(A @ sol - X, axis=1)
    return AffineMap(M, res, float(np.sqrt(np.mean(res**2))), float(np.max(res)))


def find_dot_grid(image: NDArray[np.uint8], lens: Lens, *, min_area_px: float = 50.0) -> F64:
    """The nine dark dots of a nine-point plate: (9, 2) centres in the undistorted image.

    The image is undistorted, thresholded (Otsu) and the nine largest round dark blobs are kept;
    each centre is the centroid of the dot's coverage (see :func:`_dot_centre`). They are
    ordered row by row (top row first), left to right, which holds for a plate turned less than
    about 20 deg in the image. Raises NinePointError when nine dots are not found.
    """
    if not isinstance(image, np.ndarray) or image.ndim != 2 or image.dtype != np.uint8:
        raise NinePointError("image must be a 2-D uint8 grey image")
    und = lens.undistort_image(image)
    blur = cv2.GaussianBlur(und, (0, 0), 2.0)
    _, mask = cv2.threshold(blur, 0, 255, cv2.THRESH_BINARY_INV | cv2.THRESH_OTSU)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    candidates = []
    for i in range(1, n):
        x, y, w, h, area = stats[i]
        if area < min_area_px or x == 0 or y == 0 or x + w >= und.shape[1] or y + h >= und.shape[0]:
            continue
        fill = area / (np.pi * w * h / 4.0)
        if 0.8 < w / h < 1.25 and 0.85 < fill < 1.15:
            candidates.append((area, i))
    if len(candidates) < 9:
        raise NinePointError(
            f"found {len(candidates)} round dark dots, the nine-point plate has 9: check that the whole "
            "plate is in view, evenly lit and in focus"
        )
    candidates.sort(reverse=True)
    areas = np.array([a for a, _ in candidates[:9]], dtype=float)
    if areas.min() < 0.6 * np.median(areas):
        raise NinePointError("the nine largest dots differ too much in size: something else in view looks like a dot")
    centres = [_dot_centre(und, labels, stats[i], i) for _, i in candidates[:9]]
    C = np.array(centres)
    order = np.argsort(C[:, 1])
    rows = [C[order[3 * r : 3 * r + 3]] for r in range(3)]
    return np.vstack([row[np.argsort(row[:, 0])] for row in rows])


def _dot_centre(und: NDArray[np.uint8], labels: NDArray[np.int32], stat: NDArray[np.int32], label: int) -> F64:
    """Centroid of a dark dot's coverage, insensitive to smooth illumination changes.

    Illumination multiplies paper and ink alike, so the coverage of a pixel is
    (1 - I / paper(u, v)) / (1 - rho), with paper(u, v) a plane fitted to the paper around the dot
    and rho the ink-to-paper ratio inside it. The coverage is not clipped: paper noise averages
    out instead of adding a pedestal that would pull the centroid to the window's centre.
    """
    x, y, w, h, _ = (int(v) for v in stat)
    pad = max(6, int(0.25 * max(w, h)))
    x0, y0 = max(x - pad, 0), max(y - pad, 0)
    x1, y1 = min(x + w + pad, und.shape[1]), min(y + h + pad, und.shape[0])
    patch = und[y0:y1, x0:x1].astype(np.float64)
    yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float64)
    blob = (labels[y0:y1, x0:x1] == label).astype(np.uint8)
    grown = cv2.dilate(blob, np.ones((2 * pad // 3 + 1, 2 * pad // 3 + 1), np.uint8)) > 0
    core = cv2.erode(blob, np.ones((5, 5), np.uint8)) > 0
    paper = ~grown & (labels[y0:y1, x0:x1] == 0)
    if paper.sum() < 10 or core.sum() < 5:
        raise NinePointError("a dot lies too close to another feature or the image border to be measured")
    A = np.column_stack([np.ones(paper.sum()), xx[paper], yy[paper]])
    coef, *_ = np.linalg.lstsq(A, patch[paper], rcond=None)
    level = coef[0] + coef[1] * xx + coef[2] * yy
    ratio = patch / level
    rho = float(np.median(ratio[core]))
    cover = (1.0 - ratio) / (1.0 - rho)
    window = grown  # the dot and its blurred rim; the paper beyond contributes only noise
    total = float(cover[window].sum())
    return np.array([(cover[window] * xx[window]).sum() / total, (cover[window] * yy[window]).sum() / total])
