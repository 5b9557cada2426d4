"""An annotated picture of the inspection image: the opening's and the glass's edges and the gaps.

Drawn like the corner's picture (:mod:`cellctl.vision.annotate`): each edge's fitted line through
the lens distortion (yellow) with its sub-pixel points (green fitted, red rejected), and a caption
with the gaps and the in-plane deviation, or the refusal.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from cellctl.vision.annotate import caption_png, draw_edge, shrunk_bgr
from cellctl.vision.gap import GapMeasurement
from cellctl.vision.lens import Lens


def annotate_gaps(
    image: NDArray[np.uint8],
    measurement: GapMeasurement,
    lens: Lens,
    *,
    figures: dict[str, float] | None = None,
    width_px: int = 1024,
) -> bytes:
    """PNG bytes of ``image`` with the four edges of ``measurement``; ``figures`` (gaps, dx, dy, drz) in the caption."""
    img, k = shrunk_bgr(image, width_px)
    m = measurement
    for edge in (m.opening_top, m.opening_right, m.glass_top, m.glass_right):
        if edge is not None:
            draw_edge(img, edge, lens, k, None)
    if m.ok and figures is not None:
        lines = [
            f"gaps top {figures['top_gap_mm']:.3f} mm  right {figures['right_gap_mm']:.3f} mm",
            f"glass dx={figures['dx_mm']:+.3f} mm dy={figures['dy_mm']:+.3f} mm drz={np.degrees(figures['drz_rad']):+.4f} deg",
        ]
    elif m.ok:
        lines = ["edges found"]
    else:
        lines = [f"REFUSED ({m.refusal.value if m.refusal else '?'}): {m.message}"]
    scale = max(0.4, width_px / 2048.0)
    return caption_png(img, lines, ok=m.ok, scale=scale, y=int(22 * scale / 0.5))
