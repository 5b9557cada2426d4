"""Pixel scale from a checkerboard on the assembly plane (paper section 4.1, eq. 15).

After alignment the camera looks square onto the wall at the working distance; a checkerboard
placed on the wall is imaged, the image is undistorted with the calibrated lens, and the inner
corners are found with ``cv2.findChessboardCornersSB`` (sub-pixel, and it fails fast on a frame
without a board). For every pair of neighbouring corners along the board's rows and columns,
d_xy is the printed square size and d_uv their distance in the image; eq. 15 averages the ratios:

    s = (1/n) * sum(d_xy_i / d_uv_i)   [mm per px]
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.vision.lens import Lens

F64 = NDArray[np.float64]


class ScaleCalibrationError(ValueError):
    """No usable checkerboard in the image, or bad arguments; the message says what to do."""


@dataclass(frozen=True)
class PixelScale:
    """The result of eq. 15 and how consistent its pairs were.

    ``mm_per_px`` is s; ``mm_per_px_rows``/``mm_per_px_cols`` the same mean over the pairs along
    the board's rows and its columns only (they differ if the pixels are not square or the board
    is tilted to the camera); ``ratio_std`` the standard deviation of the n ratios relative to s;
    ``corners_px`` the inner corners (rows x columns x 2) in the undistorted image.
    """

    mm_per_px: float
    n_pairs: int
    ratio_std: float
    mm_per_px_rows: float
    mm_per_px_cols: float
    corners_px: F64

    @property
    def anisotropy(self) -> float:
        """Relative difference between the row and column scales."""
        return abs(self.mm_per_px_rows - self.mm_per_px_cols) / self.mm_per_px


def scale_from_corners(corners_px: F64, square_mm: float) -> PixelScale:
    """Eq. 15 over the neighbouring pairs of a grid of corners (rows x columns x 2, undistorted px)."""
    g = np.asarray(corners_px, dtype=float)
    if g.ndim != 3 or g.shape[2] != 2 or g.shape[0] < 2 or g.shape[1] < 2:
        raise ScaleCalibrationError(f"corners must form a grid (rows >= 2, columns >= 2, 2), got shape {g.shape}")
    if not np.isfinite(square_mm) or square_mm <= 0:
        raise ScaleCalibrationError(f"square_mm must be a positive number, got {square_mm!r}")
    d_rows = np.linalg.norm(g[:, 1:] - g[:, :-1], axis=2).ravel()
    d_cols = np.linalg.norm(g[1:, :] - g[:-1, :], axis=2).ravel()
    if np.any(np.concatenate([d_rows, d_cols]) < 1.0):
        raise ScaleCalibrationError("two neighbouring corners coincide: the corner grid is not a checkerboard's")
    r_rows = square_mm / d_rows
    r_cols = square_mm / d_cols
    ratios = np.concatenate([r_rows, r_cols])
    s = float(np.mean(ratios))
    return PixelScale(
        mm_per_px=s,
        n_pairs=int(len(ratios)),
        ratio_std=float(np.std(ratios) / s),
        mm_per_px_rows=float(np.mean(r_rows)),
        mm_per_px_cols=float(np.mean(r_cols)),
        corners_px=g,
    )


def checkerboard_scale(
    image: NDArray[np.uint8],
    lens: Lens,
    inner_corners: tuple[int, int],
    square_mm: float,
    *,
    accurate: bool = True,
) -> PixelScale:
    """s of eq. 15 from an image of a checkerboard lying on the assembly plane.

    ``inner_corners`` is (columns, rows) of inner corners, OpenCV's ``patternSize``.
    ``accurate`` asks the detector to up-sample around the corners (CALIB_CB_ACCURACY: about
    0.025 px instead of 0.04 px RMS on the twin's 2048 x 2048 frames, for a few seconds more).
    Raises ScaleCalibrationError when the board is not found.
    """
    if not isinstance(image, np.ndarray) or image.ndim != 2 or image.dtype != np.uint8:
        raise ScaleCalibrationError("image must be a 2-D uint8 grey image")
    cols, rows = (int(inner_corners[0]), int(inner_corners[1]))
    if cols < 2 or rows < 2:
        raise ScaleCalibrationError(f"inner_corners must be at least (2, 2), got {inner_corners!r}")
    undistorted = lens.undistort_image(image)
    flags = cv2.CALIB_CB_ACCURACY if accurate else 0
    found, corners = cv2.findChessboardCornersSB(undistorted, (cols, rows), flags=flags)
    if not found or corners is None:
        raise ScaleCalibrationError(
            f"no checkerboard with {cols} x {rows} inner corners found; check the pattern size (inner "
            "corners, columns x rows), that the whole board with its white border is in view and in focus"
        )
    grid = corners.reshape(rows, cols, 2).astype(np.float64)
    return scale_from_corners(grid, square_mm)
