"""Rules of the inspection image's gaps that a mutation run found unguarded: an edge that fails its limits refuses
the gaps, and a window that runs out of the image (less its border margin) is refused with its settings.

Truth: the twin renders a known install with the camera square to the wall at 400 mm; the windows' geometry
(``vision.gap.start_px``, ``length_px``, ``border_margin_px`` from the template's corner) is known in pixels.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from cellctl.bench.inspection_vision import glass_at, taught_view
from cellctl.config.sim import SimConfig
from cellctl.config.vision import GapVisionConfig, VisionConfig
from cellctl.sim.camera import CameraRenderer
from cellctl.sim.image_truth import camera_pose_seeing_corner
from cellctl.sim.world import nominal_world
from cellctl.vision import Lens
from cellctl.vision.gap import GapMeasurement, GapRefusal, measure_gaps

SIM = SimConfig()
LENS = Lens.from_intrinsics(SIM.camera.intrinsics)
CONFIG = VisionConfig().gap
GAP = SIM.glass.edge_gap_mm
D = 400.0


@pytest.fixture(scope="module")
def renderer() -> CameraRenderer:
    return CameraRenderer(SIM.camera.intrinsics, SIM.camera.render)


def _inspect(renderer: CameraRenderer, corner_px: tuple[float, float], config: GapVisionConfig) -> GapMeasurement:
    """A known install (0.2 mm, -0.1 mm off, 0.3 mm deep) seen with the opening's corner at ``corner_px``."""
    world = nominal_world(SIM.world)
    template, nine_point = taught_view(renderer, world, corner_px, D)
    pose = camera_pose_seeing_corner(renderer.camera, world, corner_px, distance_mm=D)
    glass = glass_at(SIM, world, np.array([0.2, -0.1, 0.3, 0.0, 0.0, 0.0]))
    image = renderer.render(pose, world, rng=np.random.default_rng(3), glass=glass).image
    return measure_gaps(image, LENS, template, config, gap_px_expected=GAP / nine_point.mm_per_px)


def test_an_edge_scattering_past_its_limit_refuses_the_gaps(renderer: CameraRenderer) -> None:
    # The twin's glass edge scatters about 0.35 px about its line (vision.gap.max_rms_px's note): measured at
    # the default 0.6 px it passes; held to 0.05 px, the same image is refused, not measured.
    assert _inspect(renderer, (LENS.cx, LENS.cy), CONFIG).ok
    strict = CONFIG.model_copy(update={"max_rms_px": 0.05})
    m = _inspect(renderer, (LENS.cx, LENS.cy), strict)
    assert m.refusal is GapRefusal.POOR_FIT, m.message
    assert "edge fit RMS" in m.message and "refused" in m.message, m.message


def test_a_window_running_out_of_the_image_is_refused_naming_its_settings(renderer: CameraRenderer) -> None:
    # The corner 460 px from the image's left border: the top edge's window starts start_px = 440 px to its left.
    # Inside the border margin (12 px) lie only the window's pixels whose place in the raw image (the lens's
    # barrel distortion moves them about 6 px out there) is 12 px or more from the border: fewer than the 24
    # cross-sections its profile takes, so the edge cannot be measured.
    world = nominal_world(SIM.world)
    template, _ = taught_view(renderer, world, (460.0, 900.0), D)
    t = np.arange(CONFIG.start_px, CONFIG.start_px + CONFIG.length_px + 1e-9, 1.0)
    raw = LENS.distort(np.column_stack([template.u_px - t, np.full(len(t), template.v_px)]))
    inside = int(np.count_nonzero(raw[:, 0] >= CONFIG.border_margin_px))
    assert 0 < inside < CONFIG.cross_sections
    m = _inspect(renderer, (460.0, 900.0), CONFIG)
    assert m.refusal is GapRefusal.EDGE_MISSING, m.message
    found = re.search(r"the top edge's straight part \(440 to 1000 px from the template's corner\) has only (\d+) px", m.message)
    assert found, m.message
    assert int(found.group(1)) == inside
    assert "vision.gap.cross_sections = 24" in m.message, m.message
