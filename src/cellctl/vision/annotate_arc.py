"""An annotated picture of an arc-corner shot (issue 21), as PNG bytes, in the corner picture's style.

Drawn on the raw image (shrunk): the ROI (blue), the arc's sub-pixel points (green: fitted, red:
left out), the fitted arc through the lens (yellow; an ellipse in the ideal image where fy is not
fx), the top edge's straight line where it gave the orientation, the centre (cyan cross), the
taught centre (magenta cross, with an arrow), and a caption with the result or the refusal.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.config.vision import RoiConfig
from cellctl.geometry.planar import PlanarOffset
from cellctl.vision.annotate import (
    _BLUE, _CYAN, _GREEN, _MAGENTA, _RED, _YELLOW, _arrow, _cross, _near, _pt, caption_png, shrunk_bgr,
)
from cellctl.vision.arc_corner import ArcCornerMeasurement
from cellctl.vision.corner import CornerFeatures
from cellctl.vision.lens import Lens


def _polyline(img: NDArray[np.uint8], ideal: NDArray[np.float64], lens: Lens, k: float, colour: tuple[int, int, int]) -> None:
    keep = np.all((ideal > -200) & (ideal < np.array([lens.width_px, lens.height_px]) + 200), axis=1)
    if keep.sum() >= 2:
        poly = np.rint((lens.distort(ideal[keep]) + 0.5) * k - 0.5).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(img, [poly], False, colour, 1, cv2.LINE_AA)


def annotate_arc(
    image: NDArray[np.uint8], m: ArcCornerMeasurement, lens: Lens, roi: RoiConfig, *,
    taught: CornerFeatures | None = None, offset: PlanarOffset | None = None, width_px: int = 1024,
) -> bytes:
    """The annotated picture of the arc shot ``m`` on ``image``, with the detector's ``roi``."""
    img, k = shrunk_bgr(image, width_px)
    x, y, w, h = roi.x_px, roi.y_px, roi.width_px, roi.height_px
    cv2.rectangle(img, _pt(np.array([x, y], float), k), _pt(np.array([x + w - 1, y + h - 1], float), k), _BLUE, 1)
    pts = lens.distort(m.points_ideal) if len(m.points_ideal) else np.zeros((0, 2))
    q = np.rint((pts + 0.5) * k - 0.5).astype(np.int64)
    inl = m.inliers if len(m.inliers) == len(q) else np.zeros(len(q), bool)
    ok = (q[:, 0] >= 0) & (q[:, 0] < img.shape[1]) & (q[:, 1] >= 0) & (q[:, 1] < img.shape[0])
    img[q[ok, 1], q[ok, 0]] = np.where(inl[ok, None], np.array(_GREEN), np.array(_RED))
    # The centre through the lens only near the image (a refused fit's can lie 1e9 px away: not drawn).
    centre_raw = None
    if m.centre_px is not None and _near(m.centre_px, (lens.width_px, lens.height_px))[0]:
        centre_raw = lens.distort(m.centre_px[None])[0]
    if m.centre_px is not None and m.radius_px is not None:
        a = np.linspace(-0.1, 0.5 * np.pi + 0.1, 400)  # the upper-right quarter, a little beyond
        ideal = m.centre_px + m.radius_px * np.column_stack([np.cos(a), -np.sin(a) * lens.fy / lens.fx])
        _polyline(img, ideal, lens, k, _YELLOW)
        if centre_raw is not None:
            _cross(img, centre_raw, k, _CYAN)
    top = m.orientation.top if m.orientation is not None else None
    if top is not None and top.ok:
        _polyline(img, top.line.at(np.linspace(-3000.0, 3000.0, 600)), lens, k, _YELLOW)
    if taught is not None:
        t_raw = lens.distort(np.array([[taught.u_px, taught.v_px]]))[0]
        _cross(img, t_raw, k, _MAGENTA)
        if centre_raw is not None:
            _arrow(img, t_raw, centre_raw, k, _MAGENTA)
    lines = []
    if m.ok and m.centre_px is not None:
        theta = m.orientation.theta_rad if m.orientation is not None else None
        lines.append(
            f"arc centre u={m.centre_px[0]:.2f} v={m.centre_px[1]:.2f} px  R={m.radius_px:.1f} px  "
            + (f"theta={np.degrees(theta):+.4f} deg" if theta is not None else "no orientation")
        )
        lines.append(f"coverage {m.coverage_deg:.1f} deg  rms {m.rms_px:.3f} px  sigma {m.centre_sigma_px:.3f} px")
    else:
        lines.append(f"REFUSED ({m.refusal.value if m.refusal else '?'}): {m.message}")
    if offset is not None:
        lines.append(f"offset dx={offset.dx_mm:+.3f} mm dy={offset.dy_mm:+.3f} mm dtheta={np.degrees(offset.dtheta_rad):+.4f} deg")
    scale = max(0.4, width_px / 2048.0)
    return caption_png(img, lines, ok=m.ok, scale=scale, y=int(22 * scale / 0.5))
