"""The inspection image against the twin's truth: gaps and the glass's in-plane offset, parallax, refusals.

The 200-render statistics are printed by ``python -m cellctl.bench.inspection_vision``.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from pydantic import ValidationError

from cellctl.bench.inspection_vision import glass_at, measure_inspection, taught_view
from cellctl.config.sim import SimConfig
from cellctl.config.vision import FeatureConfig, GapVisionConfig, VisionConfig
from cellctl.sim.camera import CameraRenderer
from cellctl.sim.image_truth import camera_pose_seeing_corner, glass_truth
from cellctl.sim.world import nominal_world
from cellctl.vision import Lens
from cellctl.vision.corner import CornerFeatures
from cellctl.vision.gap import GapMeasurement, GapRefusal, in_plane_from_gaps, measure_gaps

SIM = SimConfig()
LENS = Lens.from_intrinsics(SIM.camera.intrinsics)
CONFIG = VisionConfig().gap
GAP = SIM.glass.edge_gap_mm
D = 400.0


@pytest.fixture(scope="module")
def renderer() -> CameraRenderer:
    return CameraRenderer(SIM.camera.intrinsics, SIM.camera.render)


def _gaps_of(renderer: CameraRenderer, corner_px: tuple[float, float], deviation: list[float], seed: int,
             config: GapVisionConfig = CONFIG):  # type: ignore[no-untyped-def]
    """Render the glass at ``deviation`` (dX, dY, dZ mm, dRx, dRy, dRz deg) seen with the corner at ``corner_px`` and
    measure its gaps; with the scene (pose, world, glass) and the taught nine-point map."""
    world = nominal_world(SIM.world)
    glass = glass_at(SIM, world, np.concatenate([deviation[:3], np.radians(deviation[3:])]))
    template, nine_point = taught_view(renderer, world, corner_px, D)
    pose = camera_pose_seeing_corner(renderer.camera, world, corner_px, distance_mm=D)
    image = renderer.render(pose, world, rng=np.random.default_rng(seed), glass=glass).image
    m = measure_gaps(image, LENS, template, config, gap_px_expected=GAP / nine_point.mm_per_px)
    return m, (pose, world, glass), nine_point


def _measure(renderer: CameraRenderer, corner_px: tuple[float, float], deviation: list[float], seed: int, *, dz_known: bool = True):  # type: ignore[no-untyped-def]
    """The gaps of the glass at ``deviation`` (see :func:`_gaps_of`), its in-plane figures and the twin's truth."""
    m, (pose, world, glass), nine_point = _gaps_of(renderer, corner_px, deviation, seed)
    assert m.ok, m.message
    truth = glass_truth(renderer.camera, pose, world, glass, reference_along_mm=m.start_px * nine_point.mm_per_px)
    fig = in_plane_from_gaps(
        m, nine_point, nominal_gap_mm=GAP, dz_mm=truth.dz_mm if dz_known else 0.0, working_distance_mm=D,
        principal_point_px=(LENS.cx, LENS.cy),
    )
    return m, fig, truth


def _errors(fig, truth) -> dict[str, float]:  # type: ignore[no-untyped-def]
    return {
        "dx_mm": fig.dx_mm - truth.dx_mm,
        "dy_mm": fig.dy_mm - truth.dy_mm,
        "top_gap_mm": fig.top_gap_mm - truth.top_gap_mm,
        "right_gap_mm": fig.right_gap_mm - truth.right_gap_mm,
        "drz_deg": math.degrees(fig.drz_rad - truth.drz_rad),
        "top_angle_deg": math.degrees(fig.top_angle_rad - truth.top_angle_rad),
        "right_angle_deg": math.degrees(fig.right_angle_rad - truth.right_angle_rad),
    }


def _within_bars(err: dict[str, float]) -> bool:
    return all(abs(v) <= (0.01 if k.endswith("deg") else 0.02) for k, v in err.items())


@pytest.mark.parametrize("seed", [1, 2])
def test_a_known_install_is_measured_within_the_bars(renderer: CameraRenderer, seed: int) -> None:
    m, fig, truth = _measure(renderer, (LENS.cx, LENS.cy), [0.3, -0.2, 0.4, 0.0, 0.0, 0.1], seed)
    assert (truth.dx_mm, truth.dy_mm, truth.dz_mm) == pytest.approx((0.3, -0.2, 0.4))
    err = _errors(fig, truth)
    assert _within_bars(err), err
    assert all(n >= CONFIG.min_points for n in m.points.values()), m.points
    # The gaps are the nominal 5 mm moved by the offset: the truth is not the nominal one.
    assert truth.top_gap_mm == pytest.approx(GAP - 0.2 + 0.0, abs=0.1) and abs(truth.top_gap_mm - GAP) > 0.1
    # The figures ride on the twin's truth of the glass's corner in the image too.
    assert np.linalg.norm(m.glass_corner_px - truth.glass_corner_undistorted_px) < 0.3


def test_random_installs_on_random_car_bodies(renderer: CameraRenderer) -> None:
    acc = measure_inspection(renderer, SIM, LENS, CONFIG, 6, np.random.default_rng(11))
    assert acc.accepted == 6, acc.refusals
    assert acc.meets(), acc.figures()


def test_the_parallax_of_a_recessed_glass_off_axis_needs_its_correction(renderer: CameraRenderer) -> None:
    corner = (1550.0, 550.0)  # about 40 mm right of and 35 mm above the optical axis
    deviation = [0.2, 0.1, 0.5, 0.0, 0.0, -0.1]  # the glass 0.5 mm behind the wall
    _, corrected, truth = _measure(renderer, corner, deviation, 3)
    _, plain, _ = _measure(renderer, corner, deviation, 3, dz_known=False)
    assert _within_bars(_errors(corrected, truth)), _errors(corrected, truth)
    err = _errors(plain, truth)
    assert max(abs(err["dx_mm"]), abs(err["dy_mm"])) > 0.03, err  # scaled about the axis by 0.5 / 400 over ~35 mm
    assert corrected.parallax_scale == pytest.approx((D + 0.5) / D, abs=1e-4)


def test_no_glass_is_refused(renderer: CameraRenderer) -> None:
    world = nominal_world(SIM.world)
    template, nine_point = taught_view(renderer, world, (LENS.cx, LENS.cy), D)
    pose = camera_pose_seeing_corner(renderer.camera, world, (LENS.cx, LENS.cy))
    image = renderer.render(pose, world, rng=np.random.default_rng(4)).image
    m = measure_gaps(image, LENS, template, CONFIG, gap_px_expected=GAP / nine_point.mm_per_px)
    assert m.refusal is GapRefusal.NO_GLASS and "no glass" in m.message, m.message
    # Its flange's border into the seal lies near the expected gap: without the frit rule it passes for a glass.
    loose = CONFIG.model_copy(update={"frit_edge": False})
    m = measure_gaps(image, LENS, template, loose, gap_px_expected=GAP / nine_point.mm_per_px)
    assert m.refusal is not GapRefusal.NO_GLASS
    with pytest.raises(ValueError, match="refused"):
        in_plane_from_gaps(
            measure_gaps(image, LENS, template, CONFIG, gap_px_expected=66.0), nine_point, nominal_gap_mm=GAP, dz_mm=0.0,
            working_distance_mm=D, principal_point_px=(LENS.cx, LENS.cy),
        )


def test_a_glass_far_off_its_gap_and_a_camera_off_its_pose_are_refused(renderer: CameraRenderer) -> None:
    world = nominal_world(SIM.world)
    template, nine_point = taught_view(renderer, world, (LENS.cx, LENS.cy), D)
    pose = camera_pose_seeing_corner(renderer.camera, world, (LENS.cx, LENS.cy))
    glass = glass_at(SIM, world, np.array([3.0, 0.0, 0.0, 0.0, 0.0, 0.0]))  # the right gap 2 mm, not 5
    image = renderer.render(pose, world, rng=np.random.default_rng(5), glass=glass).image
    gap_px = GAP / nine_point.mm_per_px
    m = measure_gaps(image, LENS, template, CONFIG, gap_px_expected=gap_px)
    assert m.refusal is GapRefusal.GLASS_EDGE_NOT_FOUND and "right edge" in m.message, m.message
    # The same image measured with the gap it has.
    wide = CONFIG.model_copy(update={"glass_search_px": 50.0})
    assert measure_gaps(image, LENS, template, wide, gap_px_expected=gap_px).ok
    moved = CornerFeatures(template.u_px - 45.0, template.v_px - 45.0, 0.0, 0.0, 0.0)
    m = measure_gaps(image, LENS, moved, CONFIG, gap_px_expected=gap_px)
    assert m.refusal is GapRefusal.OPENING_EDGE_NOT_FOUND and "template" in m.message, m.message
    # A recipe whose feature (the seal's inner edge) is hidden under the glass is refused, not mistaken.
    seal = FeatureConfig(count_from="opening", index=0, min_step_fraction=0.08)
    inset_px = -renderer.surface_of(world).steps[-1][0] / nine_point.mm_per_px  # its template sits on the seal's edge
    taught_on_seal = CornerFeatures(template.u_px - inset_px, template.v_px + inset_px, 0.0, 0.0, 0.0)
    glass = glass_at(SIM, world, np.zeros(6))
    image = renderer.render(pose, world, rng=np.random.default_rng(6), glass=glass).image
    m = measure_gaps(image, LENS, taught_on_seal, CONFIG, gap_px_expected=gap_px, feature=seal)
    assert m.refusal is GapRefusal.OPENING_EDGE_NOT_FOUND, m.message


def test_auto_polarity_finds_the_same_edges(renderer: CameraRenderer) -> None:
    world = nominal_world(SIM.world)
    template, nine_point = taught_view(renderer, world, (LENS.cx, LENS.cy), D)
    pose = camera_pose_seeing_corner(renderer.camera, world, (LENS.cx, LENS.cy))
    glass = glass_at(SIM, world, np.array([-0.2, 0.3, 0.1, 0.0, 0.0, 0.0]))
    image = renderer.render(pose, world, rng=np.random.default_rng(8), glass=glass).image
    gap_px = GAP / nine_point.mm_per_px
    darker = measure_gaps(image, LENS, template, CONFIG, gap_px_expected=gap_px)
    auto = measure_gaps(image, LENS, template, CONFIG, gap_px_expected=gap_px, opening_polarity="auto")
    assert darker.ok and auto.ok
    for which in ("opening_top", "opening_right", "glass_top", "glass_right"):
        a, b = getattr(darker.lines, which), getattr(auto.lines, which)
        assert np.array_equal(a.point, b.point) and np.array_equal(a.direction, b.direction)
    assert set(darker.rms_px) == {"opening_top", "opening_right", "glass_top", "glass_right"}
    assert max(darker.rms_px.values()) < CONFIG.max_rms_px


def test_gap_config_is_checked_and_sits_in_the_vision_section() -> None:
    assert VisionConfig().gap == GapVisionConfig()
    with pytest.raises(ValidationError, match="glass_search_px"):
        GapVisionConfig(glass_search_px=0.0)
    with pytest.raises(ValidationError, match="min_step_fraction"):
        GapVisionConfig(min_step_fraction=1.0)
    with pytest.raises(ValueError, match="gap_px_expected"):
        measure_gaps(np.zeros((2048, 2048), np.uint8), LENS, CornerFeatures(1000.0, 1000.0, 0.0, 0.0, 0.0), CONFIG, gap_px_expected=0.0)


def test_the_benchmark_runs(capsys: pytest.CaptureFixture[str]) -> None:
    from cellctl.bench.inspection_vision import main

    assert main(["--renders", "2", "--seed", "5"]) == 0
    out = capsys.readouterr().out
    assert "2/2 accepted" in out and "|position error|: median" in out and "met" in out


def _known_install(renderer: CameraRenderer, corner_px: tuple[float, float], config: GapVisionConfig) -> GapMeasurement:
    """A known install (0.2 mm, -0.1 mm off, 0.3 mm deep) seen with the opening's corner at ``corner_px``."""
    return _gaps_of(renderer, corner_px, [0.2, -0.1, 0.3, 0.0, 0.0, 0.0], 3, config)[0]


def test_an_edge_scattering_past_its_limit_refuses_the_gaps(renderer: CameraRenderer) -> None:
    # The twin's glass edge scatters about 0.35 px about its line (vision.gap.max_rms_px's note): measured at
    # the default 0.6 px it passes; held to 0.05 px, the same image is refused, not measured.
    assert _known_install(renderer, (LENS.cx, LENS.cy), CONFIG).ok
    strict = CONFIG.model_copy(update={"max_rms_px": 0.05})
    m = _known_install(renderer, (LENS.cx, LENS.cy), strict)
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
    m = _known_install(renderer, (460.0, 900.0), CONFIG)
    assert m.refusal is GapRefusal.EDGE_MISSING, m.message
    found = re.search(r"the top edge's straight part \(440 to 1000 px from the template's corner\) has only (\d+) px", m.message)
    assert found, m.message
    assert int(found.group(1)) == inside
    assert "vision.gap.cross_sections = 24" in m.message, m.message
