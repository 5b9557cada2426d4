"""Calibration targets the twin's camera can see: a checkerboard and a nine-point dot plate.

Each target is a flat printed plate. Its frame P: origin at the first feature (the top-left inner
corner of the checkerboard, the top-left dot of the nine-point plate), x to the right along the
rows of features, y down, z into the plate (away from a viewer in front of it, like the
workpiece frame T). A :class:`PlacedTarget` puts a plate at a pose ``T_B_P`` in the robot base
frame; its true feature points in B are ``points_B()``, their true image positions
``CameraModel.project(points_B, T_B_C)``.

Shading is analytic (cellctl.sim.edge_coverage): every pixel gets the exact coverage of the
straight edges near it. At a checkerboard's X junction the two edge families are combined as a
sum over the squares of separable coverages; that is exact along each edge and symmetric about
the junction, so the rendered saddle point sits on the true corner.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.geometry.pose import apply_pose, check_pose, pose_in_plane
from cellctl.sim.edge_coverage import (
    circle_sdf,
    coverage_from_sdf,
    edge_coverage,
    kernel_reach_px,
    rounded_rect_sdf,
)

F64 = NDArray[np.float64]
Jacobian = tuple[F64, F64, F64, F64]


class Target(Protocol):
    """A flat printed target in its own plane (frame P, mm)."""

    @property
    def name(self) -> str: ...

    def feature_points_P(self) -> F64:
        """The true feature points (N, 3) in P, in the order a detector reports them."""
        ...

    def plate_rect(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """The plate's outline in P: (centre, half size), an axis-aligned rectangle."""
        ...

    def shade(self, x: F64, y: F64, jac: Jacobian, sigma_px: float) -> F64:
        """The printed grey level (DN at full illumination) seen by pixels hitting P at (x, y).

        ``jac`` is the plane-from-pixel Jacobian at each pixel (mm/px), ``sigma_px`` the optics'
        blur. Only called for pixels on or near the plate.
        """
        ...

    @property
    def plate_dn(self) -> float:
        """The plate's own (paper) grey level, at full illumination."""
        ...

    def uniform_level(self, x: F64, y: F64, margin: F64) -> tuple[NDArray[np.bool_], F64]:
        """Whether every point within ``margin`` (mm) of (x, y) on the plate prints one grey
        level (no pattern edge that close), and that level."""
        ...


def _positive(name: str, value: float) -> None:
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")


def _grey(name: str, value: float) -> None:
    if not np.isfinite(value) or not 0 <= value <= 255:
        raise ValueError(f"{name} must be a grey level in [0, 255], got {value!r}")


def _dark_on_white(dark_name: str, dark_dn: float, white_dn: float) -> None:
    """``white_dn`` and the dark level are grey levels, the dark one below the white."""
    _grey("white_dn", white_dn)
    _grey(dark_name, dark_dn)
    if dark_dn >= white_dn:
        raise ValueError(f"{dark_name} ({dark_dn}) must be darker than white_dn ({white_dn})")


def _grid_P(cols: int, rows: int, pitch_mm: float) -> F64:
    """Grid points (cols * rows, 3) at (i * pitch_mm, j * pitch_mm, 0) in P, row by row (j), i fastest."""
    j, i = np.mgrid[0:rows, 0:cols]
    return np.column_stack([i.ravel() * pitch_mm, j.ravel() * pitch_mm, np.zeros(cols * rows)])


def _grid_line_coverages(coord_mm: F64, nearest: F64, pitch_mm: float, ju: F64, jv: F64, sigma_px: float) -> list[F64]:
    """Coverage of the half-planes {coordinate > (nearest + k) pitch_mm}, k = -1, 0, 1 (lines across one axis).

    ``ju, jv``: that coordinate's derivatives along the pixel's u and v (mm/px). The edge's image normal
    is the same for the three lines, so it is computed once (:func:`coverage_from_sdf` for a gradient
    along the axis, whose result this is to the bit).
    """
    norm = np.hypot(ju, jv)
    nu, nv = -ju / norm, -jv / norm
    reach = kernel_reach_px(sigma_px)
    # The lines either side are at least half a pitch away: where that is beyond the kernel's reach in
    # every pixel, the half-planes beyond them cover wholly (k = -1) and not at all (k = 1).
    neighbours_clear = norm.size == 0 or 0.5 * pitch_mm / float(norm.max()) > reach * (1.0 + 1e-9)
    out: list[F64] = []
    for k in (-1, 0, 1):
        if k and neighbours_clear:
            out.append(np.full_like(coord_mm, 1.0 if k < 0 else 0.0))
            continue
        d_px = (coord_mm - (nearest + k) * pitch_mm) / norm
        cover = (d_px > 0.0).astype(np.float64)
        near = np.abs(d_px) < reach
        if np.any(near):
            cover[near] = edge_coverage(d_px[near], nu[near], nv[near], sigma_px)
        out.append(cover)
    return out


def _check_pixel_size(name: str, size_mm: float, jac: Jacobian, sigma_px: float, need: float) -> None:
    """Refuse a pattern whose features are too small in the image for the local shading model."""
    a, b, c, d = jac
    stretch = np.sqrt(a * a + b * b + c * c + d * d)  # >= the largest mm-per-px of the mapping
    smallest_px = size_mm / float(np.max(stretch)) if stretch.size else np.inf
    if smallest_px < need * kernel_reach_px(sigma_px):
        raise ValueError(
            f"{name} appears only {smallest_px:.1f} px large in the image; it must be at least "
            f"{need * kernel_reach_px(sigma_px):.1f} px: move the camera closer or use a larger target"
        )


@dataclass(frozen=True)
class Checkerboard:
    """A printed checkerboard.

    Attributes:
        inner_corners: (columns, rows) of inner corners, OpenCV's ``patternSize``.
        square_mm: side of one square.
        border_mm: white margin around the squares (OpenCV's detector wants about one square).
        white_dn, black_dn: printed grey levels at full illumination.

    The squares form (columns + 1) x (rows + 1) cells; the top-left cell is black. Inner corner
    (i, j) is at (i * square_mm, j * square_mm, 0) in P; ``feature_points_P`` lists them row by
    row (j), i fastest.
    """

    inner_corners: tuple[int, int] = (9, 6)
    square_mm: float = 10.0
    border_mm: float = 10.0
    white_dn: float = 200.0
    black_dn: float = 25.0

    def __post_init__(self) -> None:
        cols, rows = self.inner_corners
        if int(cols) != cols or int(rows) != rows or cols < 2 or rows < 2:
            raise ValueError(f"inner_corners must be two integers >= 2, got {self.inner_corners!r}")
        _positive("square_mm", self.square_mm)
        if not np.isfinite(self.border_mm) or self.border_mm < 0:
            raise ValueError(f"border_mm must be a finite number >= 0, got {self.border_mm!r}")
        _dark_on_white("black_dn", self.black_dn, self.white_dn)

    @property
    def name(self) -> str:
        return f"checkerboard {self.inner_corners[0]}x{self.inner_corners[1]} @ {self.square_mm:g} mm"

    @property
    def plate_dn(self) -> float:
        return self.white_dn

    def feature_points_P(self) -> F64:
        return _grid_P(*self.inner_corners, self.square_mm)

    def plate_rect(self) -> tuple[tuple[float, float], tuple[float, float]]:
        cols, rows = self.inner_corners
        s, m = self.square_mm, self.border_mm
        x0, x1 = -s - m, cols * s + m
        y0, y1 = -s - m, rows * s + m
        return ((x0 + x1) / 2.0, (y0 + y1) / 2.0), ((x1 - x0) / 2.0, (y1 - y0) / 2.0)

    def _cell_level(self, x: F64, y: F64) -> F64:
        cols, rows = self.inner_corners
        c = np.floor(x / self.square_mm) + 1.0
        r = np.floor(y / self.square_mm) + 1.0
        black = (c >= 0) & (c <= cols) & (r >= 0) & (r <= rows) & (np.mod(c + r, 2) == 0)
        return np.where(black, self.black_dn, self.white_dn)

    def uniform_level(self, x: F64, y: F64, margin: F64) -> tuple[NDArray[np.bool_], F64]:
        s = self.square_mm
        to_line = np.minimum(np.abs(x - np.rint(x / s) * s), np.abs(y - np.rint(y / s) * s))
        return to_line > margin, self._cell_level(x, y)

    def shade(self, x: F64, y: F64, jac: Jacobian, sigma_px: float) -> F64:
        _check_pixel_size("a checkerboard square", self.square_mm, jac, sigma_px, 1.0)
        cols, rows = self.inner_corners
        s = self.square_mm
        # Cell c spans x in [(c - 1) s, c s] (cell 0 is the left border column of squares).
        kx = np.rint(x / s)  # nearest vertical grid line, at x = kx * s
        ky = np.rint(y / s)
        # Coverage of the half-planes beyond the lines kx - 1, kx, kx + 1 (farther ones are 0/1).
        a, b, c, d = jac
        hx = _grid_line_coverages(x, kx, s, a, b, sigma_px)
        hy = _grid_line_coverages(y, ky, s, c, d, sigma_px)
        col_cov = {0: hx[0] - hx[1], 1: hx[1] - hx[2]}  # cells kx and kx + 1
        row_cov = {0: hy[0] - hy[1], 1: hy[1] - hy[2]}
        even = np.mod(kx + ky, 2) == 0  # cell (kx, ky) is black where on the board; its neighbours alternate
        col_in = {dc: (kx + dc >= 0) & (kx + dc <= cols) for dc in (0, 1)}
        row_in = {dr: (ky + dr >= 0) & (ky + dr <= rows) for dr in (0, 1)}
        dark = np.zeros_like(x)
        for dc in (0, 1):
            for dr in (0, 1):
                black = col_in[dc] & row_in[dr] & (even if (dc + dr) % 2 == 0 else ~even)
                dark += np.where(black, col_cov[dc] * row_cov[dr], 0.0)
        return self.white_dn - (self.white_dn - self.black_dn) * dark


@dataclass(frozen=True)
class NinePointTarget:
    """A plate with nine dark dots on a 3 x 3 grid, for the nine-point pixel-to-workpiece map.

    Dot (i, j), i, j in 0..2, is centred at (i * pitch_mm, j * pitch_mm, 0) in P;
    ``feature_points_P`` lists them row by row (j), i fastest. The true image position of a dot is
    the projection of its centre (under perspective the centroid of the imaged ellipse differs
    from it by a small, computable amount; a detector that wants the truth to 0.01 px must
    correct for it).
    """

    pitch_mm: float = 40.0
    dot_diameter_mm: float = 8.0
    border_mm: float = 15.0
    white_dn: float = 200.0
    dot_dn: float = 25.0

    def __post_init__(self) -> None:
        _positive("pitch_mm", self.pitch_mm)
        _positive("dot_diameter_mm", self.dot_diameter_mm)
        if self.dot_diameter_mm >= self.pitch_mm:
            raise ValueError(
                f"dot_diameter_mm ({self.dot_diameter_mm}) must be smaller than pitch_mm ({self.pitch_mm})"
            )
        if not np.isfinite(self.border_mm) or self.border_mm < self.dot_diameter_mm / 2:
            raise ValueError(f"border_mm must be at least the dot radius, got {self.border_mm!r}")
        _dark_on_white("dot_dn", self.dot_dn, self.white_dn)

    @property
    def name(self) -> str:
        return f"nine-point plate @ {self.pitch_mm:g} mm"

    @property
    def plate_dn(self) -> float:
        return self.white_dn

    def feature_points_P(self) -> F64:
        return _grid_P(3, 3, self.pitch_mm)

    def plate_rect(self) -> tuple[tuple[float, float], tuple[float, float]]:
        half = self.pitch_mm + self.border_mm
        return (self.pitch_mm, self.pitch_mm), (half, half)

    def _nearest_dot(self, x: F64, y: F64) -> tuple[F64, F64]:
        p = self.pitch_mm
        return np.clip(np.rint(x / p), 0, 2) * p, np.clip(np.rint(y / p), 0, 2) * p

    def uniform_level(self, x: F64, y: F64, margin: F64) -> tuple[NDArray[np.bool_], F64]:
        ci, cj = self._nearest_dot(x, y)
        sd = np.hypot(x - ci, y - cj) - self.dot_diameter_mm / 2.0
        return np.abs(sd) > margin, np.where(sd < 0.0, self.dot_dn, self.white_dn)

    def shade(self, x: F64, y: F64, jac: Jacobian, sigma_px: float) -> F64:
        gap = self.pitch_mm - self.dot_diameter_mm  # clear paper between neighbouring dots
        _check_pixel_size("the gap between dots", gap, jac, sigma_px, 2.0)
        ci, cj = self._nearest_dot(x, y)
        sd, gx, gy = circle_sdf(x, y, ci, cj, self.dot_diameter_mm / 2.0)
        cov = coverage_from_sdf(sd, gx, gy, jac, sigma_px)
        return self.white_dn - (self.white_dn - self.dot_dn) * cov


@dataclass(frozen=True)
class PlacedTarget:
    """A target at a pose in the world: its frame P in the robot base frame."""

    target: Checkerboard | NinePointTarget
    T_B_P: NDArray[np.float64]

    def __post_init__(self) -> None:
        object.__setattr__(self, "T_B_P", check_pose(self.T_B_P, "T_B_P"))

    def points_B(self) -> F64:
        """The true feature points (N, 3) in the robot base frame."""
        return apply_pose(self.T_B_P, self.target.feature_points_P())

    def plate_sdf(self, x: F64, y: F64) -> tuple[F64, F64, F64]:
        """Signed distance (mm) to the plate's outline in P, and its gradient."""
        centre, half = self.target.plate_rect()
        return rounded_rect_sdf(x, y, centre, half, 0.0)


def place_on_world_plane(
    T_B_F: ArrayLike, offset_xy_mm: tuple[float, float], angle_rad: float = 0.0
) -> NDArray[np.float64]:
    """A pose T_B_P lying in the x-y plane of frame F (e.g. the wall's T), shifted and turned in it."""
    return pose_in_plane(T_B_F, offset_xy_mm, angle_rad)
