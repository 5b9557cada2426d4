"""Placing the twin camera's random disturbances (RenderConfig.disturbances) in one frame.

Both draw from the frame's rng a fixed number of values whatever is visible, so later draws (the
sensor noise) do not depend on the view.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from cellctl.config.render import GlareConfig, OcclusionConfig
from cellctl.sim.camera_model import CameraModel
from cellctl.sim.image_truth import EDGES, edge_curve_px, visible_edge_interval
from cellctl.sim.world import World

Occluder = tuple[tuple[float, float], tuple[float, float], float]
"""An occluding strip: centre (x, y) and half size in T (mm), and its level (DN)."""


def plan_occlusion(
    occ: OcclusionConfig,
    camera: CameraModel,
    T_B_C: NDArray[np.float64],
    world: World,
    rng: np.random.Generator,
    wall: float,
    opening: float,
    applied: dict[str, object],
) -> Occluder | None:
    """Where the occluder lies (None when no chosen edge is visible); records it in ``applied``."""
    intervals = {e: visible_edge_interval(camera, T_B_C, world, e) for e in EDGES}
    choices = [e for e in EDGES if intervals[e] is not None] if occ.edge == "random" else [occ.edge]
    draw = rng.random(2)  # always two draws, so later draws do not depend on visibility
    pick = min(int(draw[0] * len(choices)), len(choices) - 1) if choices else 0
    a_pick = float(draw[1])
    if not choices or intervals[choices[pick]] is None:
        return None
    edge = choices[pick]
    a0, a1 = intervals[edge]  # type: ignore[misc]
    length = occ.edge_fraction * (a1 - a0)
    start = a0 + a_pick * (a1 - a0 - length)
    mid = start + length / 2.0
    if edge == "top":
        centre, half = (-mid, 0.0), (length / 2.0, occ.width_mm / 2.0)
    else:
        centre, half = (0.0, mid), (occ.width_mm / 2.0, length / 2.0)
    level = wall if occ.kind == "wall_like" else opening
    applied.update(occluded_edge=edge, occluded_span_mm=(start, start + length), occluder_dn=level)
    return centre, half, level


def add_glare(
    glare: GlareConfig,
    camera: CameraModel,
    signal: NDArray[np.float32],
    T_B_C: NDArray[np.float64],
    world: World,
    rng: np.random.Generator,
    applied: dict[str, object],
) -> None:
    """Add a glare spot to ``signal`` (in place); records it in ``applied``."""
    w, h = camera.width, camera.height
    centre: tuple[float, float] | None = None
    draw = rng.random(4)
    if glare.on_edge:
        intervals = [(e, iv) for e in EDGES if (iv := visible_edge_interval(camera, T_B_C, world, e)) is not None]
        if intervals:
            edge, (a0, a1) = intervals[int(draw[0] * len(intervals)) % len(intervals)]
            uv = edge_curve_px(camera, T_B_C, world, edge, [a0 + draw[1] * (a1 - a0)])[0]
            offset = (draw[2:] - 0.5) * glare.sigma_px
            centre = (float(uv[0] + offset[0]), float(uv[1] + offset[1]))
    if centre is None:
        centre = (float(draw[2] * (w - 1)), float(draw[3] * (h - 1)))
    reach = 5.0 * glare.sigma_px
    u0, u1 = max(0, int(centre[0] - reach)), min(signal.shape[1], int(centre[0] + reach) + 1)
    v0, v1 = max(0, int(centre[1] - reach)), min(signal.shape[0], int(centre[1] + reach) + 1)
    if u1 > u0 and v1 > v0:
        gu = np.exp(-0.5 * ((np.arange(u0, u1) - centre[0]) / glare.sigma_px) ** 2).astype(np.float32)
        gv = np.exp(-0.5 * ((np.arange(v0, v1) - centre[1]) / glare.sigma_px) ** 2).astype(np.float32)
        signal[v0:v1, u0:u1] += np.float32(glare.peak_dn) * gv[:, None] * gu[None, :]
    applied.update(glare_center_px=centre, glare_peak_dn=glare.peak_dn, glare_sigma_px=glare.sigma_px)
