"""The checkerboard: its geometry, and finding its inner corners in an image.

Finding is bounded in time, as a production tool must be (DESIGN.md section 7): OpenCV's
``findChessboardCornersSB`` looks for the board on the image shrunk to at most
``search_max_px`` (it fails in well under a second when there is no board, where the classic
detector can take minutes on a 2048 x 2048 frame). The corners found there are then refined on
the full-resolution image:

- ``"subpix"`` (default): ``cv2.cornerSubPix`` on the full image, window sized from the corner
  spacing. On the twin's renders it measured 0.026 px RMS against the true corners at 0.11 s per
  2048 x 2048 view;
- ``"sb"``: ``findChessboardCornersSB`` with ``CALIB_CB_ACCURACY`` again on a crop around the
  board: 0.02-0.04 px RMS at about 1 s per view.

The corner order is made unique: corner k = j * cols + i is the board point (i, j) * square_mm in
the board frame P (x along the rows, y down, z into the board; top-left cell black). OpenCV may
start at any end of the grid; the order is fixed by the grid's handedness (P seen from the front
has x cross y pointing away from the camera) and by the colour of the cell beyond corner 0, which
must be black. That settles it only for a board with no 180 degree symmetry: the numbers of inner
corners must be one odd and one even (:class:`BoardSpec` refuses others).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]
Refine = Literal["subpix", "sb"]

_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 60, 1e-4)


@dataclass(frozen=True)
class BoardSpec:
    """A printed checkerboard: ``inner_corners`` = (columns, rows), OpenCV's ``patternSize``."""

    inner_corners: tuple[int, int]
    square_mm: float

    def __post_init__(self) -> None:
        cols, rows = self.inner_corners
        if int(cols) != cols or int(rows) != rows or cols < 3 or rows < 3:
            raise ValueError(f"board inner_corners must be two integers >= 3, got {self.inner_corners!r}")
        if (cols + rows) % 2 == 0:
            raise ValueError(
                f"board inner_corners {self.inner_corners} look the same turned by 180 deg, so the corner "
                "order (and every pose from it) would be ambiguous; use one odd and one even number, e.g. (11, 8)"
            )
        if not np.isfinite(self.square_mm) or self.square_mm <= 0:
            raise ValueError(f"board square_mm must be a positive number, got {self.square_mm!r}")

    @property
    def count(self) -> int:
        return int(self.inner_corners[0] * self.inner_corners[1])

    def object_points(self) -> F64:
        """The inner corners (N, 3) in the board frame P, in detection order (rows j, i fastest)."""
        cols, rows = self.inner_corners
        j, i = np.mgrid[0:rows, 0:cols]
        return np.column_stack([i.ravel(), j.ravel(), np.zeros(cols * rows)]) * float(self.square_mm)

    def as_dict(self) -> dict[str, object]:
        return {"inner_corners": list(self.inner_corners), "square_mm": float(self.square_mm)}

    def outline(self, border_mm: float) -> F64:
        """The printed plate's four corners (4, 3) in P: the squares and a white border of ``border_mm``."""
        cols, rows = self.inner_corners
        s, m = float(self.square_mm), float(border_mm)
        x0, x1, y0, y1 = -s - m, cols * s + m, -s - m, rows * s + m
        return np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])


@dataclass(frozen=True)
class BoardDetection:
    """The board in one image: its corners (N, 2) in raw pixels, or the reason it was not found.

    ``sharpness_px`` is OpenCV's edge-width estimate of the board (the black-to-white transition,
    below about 3 px for a sharp image); ``spacing_px`` the smallest distance between neighbouring
    corners; ``seconds`` the time the search took.
    """

    found: bool
    corners_px: F64 | None
    reason: str
    sharpness_px: float | None = None
    spacing_px: float | None = None
    seconds: float = 0.0


def _grid(corners: F64, cols: int, rows: int) -> F64:
    return corners.reshape(rows, cols, 2)


def _handedness(g: F64) -> float:
    """z of (x direction) cross (y direction) of the grid in the image (v down): > 0 seen from the front."""
    dx = g[0, -1] - g[0, 0]
    dy = g[-1, 0] - g[0, 0]
    return float(dx[0] * dy[1] - dx[1] * dy[0])


def _sample(image: NDArray[np.uint8], p: F64) -> float:
    h, w = image.shape
    x = int(np.clip(round(float(p[0])), 0, w - 1))
    y = int(np.clip(round(float(p[1])), 0, h - 1))
    patch = image[max(0, y - 2) : y + 3, max(0, x - 2) : x + 3]
    return float(np.mean(patch))


def _orient(image: NDArray[np.uint8], corners: F64, cols: int, rows: int) -> F64 | None:
    """Reorder corners so that corner 0 is the top-left inner corner of the board frame P."""
    g = _grid(corners, cols, rows)
    candidates = [g, g[::-1, ::-1], g[:, ::-1], g[::-1, :]]
    fronts = [c for c in candidates if _handedness(c) > 0.0]
    for c in fronts:
        c0, cx, cy = c[0, 0], c[0, 1], c[1, 0]
        outer = c0 + 0.5 * (c0 - cx) + 0.5 * (c0 - cy)  # the black top-left cell
        beside = c0 + 0.5 * (cx - c0) + 0.5 * (c0 - cy)  # the white cell right of it
        if _sample(image, outer) < _sample(image, beside):
            return c.reshape(-1, 2).copy()
    return None


def _min_spacing(corners: F64, cols: int, rows: int) -> float:
    g = _grid(corners, cols, rows)
    d1 = np.linalg.norm(np.diff(g, axis=1), axis=2).min()
    d2 = np.linalg.norm(np.diff(g, axis=0), axis=2).min()
    return float(min(d1, d2))


def find_board(
    image: NDArray[np.uint8],
    spec: BoardSpec,
    *,
    search_max_px: int = 1024,
    refine: Refine = "subpix",
    sharpness: bool = True,
) -> BoardDetection:
    """The board's inner corners in ``image`` (raw pixels, distortion included), or why not.

    Never raises for a missing or unusable board: the answer says what was wrong.
    """
    t0 = time.perf_counter()
    if not isinstance(image, np.ndarray) or image.ndim != 2 or image.dtype != np.uint8:
        raise ValueError("image must be a 2-D uint8 numpy array (a mono frame)")
    if refine not in ("subpix", "sb"):
        raise ValueError(f"refine must be 'subpix' or 'sb', got {refine!r}")
    cols, rows = spec.inner_corners
    h, w = image.shape
    factor = max(1, int(np.ceil(max(h, w) / float(search_max_px))))
    small = image if factor == 1 else cv2.resize(image, (w // factor, h // factor), interpolation=cv2.INTER_AREA)
    ok, found = False, None
    for flags in (0, cv2.CALIB_CB_NORMALIZE_IMAGE):  # plain first; equalised for uneven lighting
        ok, found = cv2.findChessboardCornersSB(small, (cols, rows), flags=flags)
        if ok and found is not None:
            break
    if not ok or found is None:
        return BoardDetection(
            False, None,
            f"no {cols} x {rows} checkerboard found (is the whole board with its white border in view, lit and in focus?)",
            seconds=time.perf_counter() - t0,
        )
    coarse = (found.reshape(-1, 2).astype(np.float64) + 0.5) * factor - 0.5
    spacing = _min_spacing(coarse, cols, rows)
    if spacing < 8.0:
        return BoardDetection(
            False, None,
            f"board squares are only {spacing:.1f} px wide in the image; move closer or use a larger board",
            spacing_px=spacing, seconds=time.perf_counter() - t0,
        )
    if refine == "subpix":
        half = int(np.clip(0.3 * spacing, 3, 15))
        refined = cv2.cornerSubPix(image, coarse.astype(np.float32).reshape(-1, 1, 2), (half, half), (-1, -1), _SUBPIX_CRITERIA)
        corners = refined.reshape(-1, 2).astype(np.float64)
    else:
        margin = int(1.5 * spacing)
        x0, y0 = np.maximum(np.floor(coarse.min(axis=0)) - margin, 0).astype(int)
        x1, y1 = np.minimum(np.ceil(coarse.max(axis=0)) + margin, [w, h]).astype(int)
        crop = np.ascontiguousarray(image[y0:y1, x0:x1])
        ok, fine = cv2.findChessboardCornersSB(crop, (cols, rows), flags=cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not ok or fine is None:
            return BoardDetection(
                False, None, "the board was found at reduced scale but not at full resolution (blurred or partly hidden?)",
                spacing_px=spacing, seconds=time.perf_counter() - t0,
            )
        corners = fine.reshape(-1, 2).astype(np.float64) + [x0, y0]
        # The full-resolution search may order the grid differently; match it to the coarse one.
        if np.linalg.norm(corners[0] - coarse[0]) > np.linalg.norm(corners[-1] - coarse[0]):
            corners = corners[::-1].copy()
    if np.max(np.linalg.norm(corners - coarse, axis=1)) > max(2.0 * factor, 0.25 * spacing):
        return BoardDetection(
            False, None, "corner refinement moved corners too far from the detection (blur, glare or occlusion?)",
            spacing_px=spacing, seconds=time.perf_counter() - t0,
        )
    oriented = _orient(image, corners, cols, rows)
    if oriented is None:
        return BoardDetection(
            False, None,
            "could not tell the board's orientation (no dark cell beyond the first corner seen from the front); "
            "check that the board's top-left cell is black and the board is not seen from behind",
            spacing_px=spacing, seconds=time.perf_counter() - t0,
        )
    sharp = None
    if sharpness:
        stats = cv2.estimateChessboardSharpness(image, (cols, rows), oriented.astype(np.float32).reshape(-1, 1, 2))
        sharp = float(stats[0][0])
    return BoardDetection(True, oriented, "ok", sharp, spacing, time.perf_counter() - t0)
