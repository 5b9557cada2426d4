"""An annotated picture of a corner measurement, as PNG bytes, for the dashboard and for debugging.

Drawn on the raw image (shrunk to ``width_px``): the region of interest (blue), the arc left out
around the corner (grey), the sub-pixel edge points (green: fitted, red: rejected), the fitted
lines and the circle fitted to the corner arc (yellow, drawn through the lens distortion so they
lie on the raw edges), the corner (cyan
cross), the taught corner (magenta cross) with an arrow from it to the corner, and a caption with
the result or the refusal.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.planar import PlanarOffset
from cellctl.vision.corner import CornerFeatures, CornerMeasurement, EdgeMeasurement
from cellctl.vision.lens import Lens

_BLUE = (255, 128, 0)
_GREEN = (0, 200, 0)
_RED = (0, 0, 255)
_YELLOW = (0, 230, 255)
_CYAN = (255, 255, 0)
_MAGENTA = (255, 0, 255)
_GREY = (160, 160, 160)
_WHITE = (255, 255, 255)


_REACH = 1.0  # image sizes beyond the image edge a point may lie and still be drawn (its lines clipped)


def _pt(p: NDArray[np.float64], k: float) -> tuple[int, int]:
    return int(round((p[0] + 0.5) * k - 0.5)), int(round((p[1] + 0.5) * k - 0.5))


def _near(points: NDArray[np.float64], size_px: tuple[float, float], reach: float = _REACH) -> NDArray[np.bool_]:
    """Which image points (N, 2) in px are finite and within ``reach`` image sizes of the image (width, height).

    A point further off is not drawn: OpenCV takes int32 pixels (a refused fit's centre can lie 1e9 px away),
    and the lens model holds only about the image.
    """
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    size = np.asarray(size_px, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.all(np.isfinite(p) & (p >= -reach * size) & (p <= (1.0 + reach) * size), axis=1)


def _picture_size(img: NDArray[np.uint8], k: float) -> tuple[float, float]:
    """The image's (width, height) in its own px, of the picture drawn ``k`` times smaller."""
    return img.shape[1] / k, img.shape[0] / k


def _line(img: NDArray[np.uint8], a: tuple[int, int], b: tuple[int, int], colour: tuple[int, int, int], *, arrow: bool = False) -> None:
    """A line from a to b (picture px) clipped to the picture (cv2.clipLine); an arrow's head only where its tip is in view."""
    h, w = img.shape[:2]
    visible, a_in, b_in = cv2.clipLine((0, 0, w, h), a, b)
    if not visible:
        return
    if arrow and tuple(b_in) == tuple(b):
        cv2.arrowedLine(img, a, b, colour, 2, cv2.LINE_AA, tipLength=0.2)
    else:
        cv2.line(img, a_in, b_in, colour, 2, cv2.LINE_AA)


def _cross(img: NDArray[np.uint8], p: NDArray[np.float64], k: float, colour: tuple[int, int, int], size: int = 12) -> None:
    """A cross at the raw image point p (px); none where p is not finite or far off the image (:func:`_near`)."""
    if not _near(p, _picture_size(img, k))[0]:
        return
    c = _pt(p, k)
    _line(img, (c[0] - size, c[1]), (c[0] + size, c[1]), colour)
    _line(img, (c[0], c[1] - size), (c[0], c[1] + size), colour)


def _arrow(img: NDArray[np.uint8], tail: NDArray[np.float64], tip: NDArray[np.float64], k: float, colour: tuple[int, int, int]) -> None:
    """An arrow between raw image points (px), clipped to the picture; none where either is far off the image."""
    if not np.all(_near(np.stack([tail, tip]), _picture_size(img, k))):
        return
    a, b = _pt(tail, k), _pt(tip, k)
    if a != b:
        _line(img, a, b, colour, arrow=True)


def draw_edge(img: NDArray[np.uint8], edge: EdgeMeasurement, lens: Lens, k: float, corner: NDArray[np.float64] | None) -> None:
    # The fitted line from the corner (or its points' start) across the image, through the distortion.
    t0 = float(edge.line.along(corner[None, :])[0]) if corner is not None else float(edge.line.along(edge.points_ideal).min())
    t = np.linspace(t0, t0 + 3000.0, 600)
    ideal = edge.line.at(t)
    ideal = ideal[np.all((ideal > -200) & (ideal < np.array([lens.width_px, lens.height_px]) + 200), axis=1)]
    if len(ideal) >= 2:
        raw = lens.distort(ideal)
        poly = np.rint((raw + 0.5) * k - 0.5).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(img, [poly], False, _YELLOW, 1, cv2.LINE_AA)
    # The points on top of the line, so rejected ones stand out.
    for pts, colour in ((edge.points_raw[~edge.inliers], _RED), (edge.points_raw[edge.inliers], _GREEN)):
        if len(pts) == 0:
            continue
        q = np.rint((pts + 0.5) * k - 0.5).astype(np.int64)
        h, w = img.shape[:2]
        for du, dv in ((0, 0), (1, 0), (0, 1), (1, 1)):  # 2 x 2 px dots
            x, y = q[:, 0] + du, q[:, 1] + dv
            ok = (x >= 0) & (x < w) & (y >= 0) & (y < h)
            img[y[ok], x[ok]] = colour


def annotate(
    image: NDArray[np.uint8],
    measurement: CornerMeasurement,
    lens: Lens,
    *,
    taught: CornerFeatures | None = None,
    offset: PlanarOffset | None = None,
    width_px: int = 1024,
) -> bytes:
    """The annotated picture of ``measurement`` on ``image`` as PNG bytes, ``width_px`` wide."""
    img, k = shrunk_bgr(image, width_px)
    m = measurement
    roi = m.roi
    cv2.rectangle(
        img,
        _pt(np.array([roi.x_px, roi.y_px], float), k),
        _pt(np.array([roi.x_px + roi.width_px - 1, roi.y_px + roi.height_px - 1], float), k),
        _BLUE,
        1,
    )
    if m.corner_raw_px is not None and _near(m.corner_raw_px, _picture_size(img, k))[0]:
        cv2.circle(img, _pt(m.corner_raw_px, k), int(round(m.arc_exclusion_px * k)), _GREY, 1, cv2.LINE_AA)
    for edge in (m.top, m.right):
        if edge is not None:
            draw_edge(img, edge, lens, k, m.corner_px)
    if m.arc is not None:
        arc = m.arc
        ang = np.linspace(0.0, 2.0 * np.pi, 720)
        circle = arc.centre_px + arc.radius_px * np.column_stack([np.cos(ang), np.sin(ang)])
        d = arc.points_ideal[arc.inliers] - arc.centre_px
        if len(d):
            # Only the part of the circle the arc points span.
            a = np.arctan2(d[:, 1], d[:, 0])
            mid = np.arctan2(np.mean(np.sin(a)), np.mean(np.cos(a)))
            rel = np.angle(np.exp(1j * (ang - mid)))
            lo, hi = np.min(np.angle(np.exp(1j * (a - mid)))), np.max(np.angle(np.exp(1j * (a - mid))))
            part = circle[(rel >= lo) & (rel <= hi)]
            part = part[_near(part, (lens.width_px, lens.height_px))]
            if len(part) >= 2:
                poly = np.rint((lens.distort(part) + 0.5) * k - 0.5).astype(np.int32).reshape(-1, 1, 2)
                cv2.polylines(img, [poly], False, _YELLOW, 1, cv2.LINE_AA)
        q = np.rint((arc.points_raw + 0.5) * k - 0.5).astype(np.int64)
        ok = (q[:, 0] >= 0) & (q[:, 0] < img.shape[1]) & (q[:, 1] >= 0) & (q[:, 1] < img.shape[0])
        img[q[ok, 1], q[ok, 0]] = np.where(arc.inliers[ok, None], np.array(_GREEN), np.array(_RED))
    taught_raw = None
    if taught is not None:
        taught_raw = lens.distort(np.array([[taught.u_px, taught.v_px]]))[0]
        _cross(img, taught_raw, k, _MAGENTA)
    if m.corner_raw_px is not None:
        _cross(img, m.corner_raw_px, k, _CYAN)
        if taught_raw is not None:
            _arrow(img, taught_raw, m.corner_raw_px, k, _MAGENTA)
    lines = []
    if m.ok and m.corner_px is not None and m.top is not None and m.right is not None:
        lines.append(
            f"corner u={m.corner_px[0]:.2f} v={m.corner_px[1]:.2f} px  theta={np.degrees(m.theta_rad or 0.0):+.4f} deg"
        )
        lines.append(
            f"rms {m.top.quality.rms_px:.3f}/{m.right.quality.rms_px:.3f} px  inliers "
            f"{m.top.quality.inliers}/{m.right.quality.inliers}  contrast {m.top.quality.contrast_dn:.0f}/"
            f"{m.right.quality.contrast_dn:.0f} DN  sigma {m.corner_sigma_px:.3f} px"
        )
    else:
        lines.append(f"REFUSED ({m.refusal.value if m.refusal else '?'}): {m.message}")
    if offset is not None:
        lines.append(
            f"offset dx={offset.dx_mm:+.3f} mm dy={offset.dy_mm:+.3f} mm dtheta={np.degrees(offset.dtheta_rad):+.4f} deg"
        )
    scale = max(0.4, width_px / 2048.0)
    y = int(22 * scale / 0.5)
    return caption_png(img, lines, ok=m.ok, scale=scale, y=y)


def shrunk_bgr(image: NDArray[np.uint8], width_px: int) -> tuple[NDArray[np.uint8], float]:
    """The grey image shrunk to ``width_px`` wide as BGR for drawing, and the scale factor."""
    if not isinstance(image, np.ndarray) or image.ndim != 2 or image.dtype != np.uint8:
        raise ValueError("image must be a 2-D uint8 grey image")
    if width_px < 64:
        raise ValueError(f"width_px must be at least 64, got {width_px}")
    k = width_px / image.shape[1]
    small = cv2.resize(image, (width_px, max(1, int(round(image.shape[0] * k)))), interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(small, cv2.COLOR_GRAY2BGR), k


def caption_png(img: NDArray[np.uint8], lines: list[str], *, ok: bool, scale: float, y: int) -> bytes:
    """Write the caption lines (white, red when refused) and encode the picture as PNG."""
    for text in lines:
        cv2.putText(img, text, (8, y), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(img, text, (8, y), cv2.FONT_HERSHEY_SIMPLEX, scale, _WHITE if ok else _RED, 1, cv2.LINE_AA)
        y += int(20 * scale / 0.5)
    encoded, png = cv2.imencode(".png", img)
    if not encoded:
        raise RuntimeError("OpenCV could not encode the annotated image as PNG")
    return png.tobytes()
