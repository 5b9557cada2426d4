"""Calibration targets rendered by the twin camera, checked with OpenCV's detectors against the truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cellctl.config.mounting import CameraIntrinsics
from cellctl.config.render import RenderConfig
from cellctl.config.sim import WorldConfig
from cellctl.geometry.pose import make_pose
from cellctl.geometry.rotation import rot_x, rot_y, rot_z
from cellctl.sim.camera import CameraRenderer
from cellctl.sim.targets import Checkerboard, NinePointTarget, PlacedTarget, place_on_world_plane
from cellctl.sim.world import nominal_world

INTR = CameraIntrinsics()


@pytest.fixture(scope="module")
def renderer() -> CameraRenderer:
    return CameraRenderer(INTR, RenderConfig())


def _board_pose(R: np.ndarray, distance_mm: float, board: Checkerboard) -> np.ndarray:
    """The board's centre on the optical axis at ``distance_mm``, turned by R (camera at B's origin)."""
    cols, rows = board.inner_corners
    centre_P = np.array([(cols - 1) * board.square_mm / 2.0, (rows - 1) * board.square_mm / 2.0, 0.0])
    return make_pose(R, np.array([0.0, 0.0, distance_mm]) - R @ centre_P)


def _match(found: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per-corner distance; OpenCV may report the grid starting from either end."""
    d1 = np.linalg.norm(found - truth, axis=1)
    d2 = np.linalg.norm(found[::-1] - truth, axis=1)
    return d1 if d1.mean() < d2.mean() else d2


@pytest.mark.parametrize(
    "R, distance, flags, mean_px, max_px",
    [
        (rot_z(0.05), 420.0, 0, 0.1, 0.25),
        # OpenCV's high-accuracy mode (up-sampling) reaches the render's own accuracy.
        (rot_y(0.45) @ rot_x(-0.3) @ rot_z(0.2), 400.0, cv2.CALIB_CB_ACCURACY, 0.04, 0.12),
    ],
    ids=["facing", "tilted"],
)
def test_checkerboard_is_found_with_sub_pixel_corners(
    renderer: CameraRenderer, R: np.ndarray, distance: float, flags: int, mean_px: float, max_px: float
) -> None:
    board = Checkerboard(inner_corners=(9, 6), square_mm=10.0, border_mm=10.0)
    placed = PlacedTarget(board, _board_pose(R, distance, board))
    T_B_C = np.eye(4)
    image = renderer.render(T_B_C, None, targets=[placed], rng=np.random.default_rng(21)).image
    ok, corners = cv2.findChessboardCornersSB(image, board.inner_corners, flags=flags)
    assert ok
    truth = renderer.project(placed.points_B(), T_B_C)
    err = _match(corners.reshape(-1, 2), truth)
    assert err.mean() < mean_px and err.max() < max_px, f"mean {err.mean():.3f} max {err.max():.3f} px"


def test_checkerboard_on_the_wall_in_front_of_the_opening() -> None:
    """Stuck on the wall beside the corner (the pixel-scale calibration of eq. 15), the board hides
    what is behind it and is found at its true corners."""
    renderer = CameraRenderer(INTR, RenderConfig())
    world = nominal_world(WorldConfig())
    board = Checkerboard(inner_corners=(7, 5), square_mm=12.0, border_mm=12.0)
    T_B_P = place_on_world_plane(world.T_B_T, (-110.0, 20.0), np.radians(3.0))
    placed = PlacedTarget(board, T_B_P)
    # Camera 400 mm in front of the board's centre, along T's axes.
    T_T_C = make_pose(np.eye(3), [-110.0 + 36.0, 20.0 + 24.0, -400.0])
    T_B_C = world.T_B_T @ T_T_C
    image = renderer.render(T_B_C, world, targets=[placed], rng=np.random.default_rng(4)).image
    ok, corners = cv2.findChessboardCornersSB(image, board.inner_corners)
    assert ok
    err = _match(corners.reshape(-1, 2), renderer.project(placed.points_B(), T_B_C))
    assert err.mean() < 0.1 and err.max() < 0.25
    # Pixel scale (eq. 15) from the truth: square size over the mean corner spacing.
    truth = renderer.project(placed.points_B(), T_B_C).reshape(5, 7, 2)
    spacing = np.mean(np.linalg.norm(np.diff(truth, axis=1), axis=2))
    assert board.square_mm / spacing == pytest.approx(400.0 / INTR.fx, rel=0.01)


def test_nine_point_dots_are_found_at_their_projected_centres(renderer: CameraRenderer) -> None:
    target = NinePointTarget(pitch_mm=40.0, dot_diameter_mm=8.0)
    R = rot_y(0.1) @ rot_x(0.05)
    T_B_P = make_pose(R, np.array([0.0, 0.0, 400.0]) - R @ np.array([40.0, 40.0, 0.0]))
    placed = PlacedTarget(target, T_B_P)
    image = renderer.render(np.eye(4), None, targets=[placed], rng=np.random.default_rng(8)).image
    truth = renderer.project(placed.points_B(), np.eye(4))
    # Dots are dark on white: the darkness-weighted centroid of each blob, over the blob and a
    # 4 px ring around it (so the paper's noise elsewhere does not weigh in).
    for uv in truth:
        u0, v0 = int(round(uv[0])), int(round(uv[1]))
        win = image[v0 - 80 : v0 + 81, u0 - 80 : u0 + 81].astype(float)
        paper = np.median(np.r_[win[0], win[-1], win[:, 0], win[:, -1]])
        dot = np.median(win[75:86, 75:86])
        blob = cv2.dilate((win < 0.5 * (paper + dot)).astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
        weight = np.clip((paper - win) / (paper - dot), 0.0, 1.0) * blob
        vv, uu = np.mgrid[v0 - 80 : v0 + 81, u0 - 80 : u0 + 81]
        centroid = np.array([(weight * uu).sum(), (weight * vv).sum()]) / weight.sum()
        # The imaged ellipse's centroid differs from the projected centre by perspective and
        # distortion (0.08 px here without noise).
        assert np.linalg.norm(centroid - uv) < 0.2
    assert len(truth) == 9


def test_band_rendering_of_targets_equals_shading_every_pixel() -> None:
    """The blocks a board or a dot plate leaves in one level (camera_blocks.TARGET_BLOCK_PX) hold what shading each
    of their pixels gives: a board and a dot plate on the wall seen askew, in a crop of no whole number of blocks."""
    w, h = 902, 698
    crop = CameraIntrinsics(width_px=w, height_px=h, cx=INTR.cx - (INTR.width_px - w) / 2, cy=INTR.cy - (INTR.height_px - h) / 2)
    fast, slow = CameraRenderer(crop, RenderConfig()), CameraRenderer(crop, RenderConfig(), band_rendering=False)
    world = nominal_world(WorldConfig())
    placed = [
        PlacedTarget(Checkerboard(inner_corners=(7, 5), square_mm=5.0, border_mm=5.0),
                     place_on_world_plane(world.T_B_T, (-110.0, 40.0), np.radians(7.0))),
        PlacedTarget(NinePointTarget(pitch_mm=10.0, dot_diameter_mm=4.0, border_mm=5.0),
                     place_on_world_plane(world.T_B_T, (-160.0, 40.0), np.radians(-4.0))),
    ]  # fmt: skip
    R = rot_y(0.3) @ rot_x(-0.2) @ rot_z(0.15)
    T_B_C = world.T_B_T @ make_pose(R, np.array([-118.0, 50.0, 0.0]) - R @ np.array([0.0, 0.0, 700.0]))
    a, _ = fast.render_signal(T_B_C, world, targets=placed, rng=np.random.default_rng(5))
    b, _ = slow.render_signal(T_B_C, world, targets=placed, rng=np.random.default_rng(5))
    assert np.array_equal(a, b)
    # Both targets are wholly in the crop, with their dark and light print (not a blank wall).
    for p in placed:
        uv = fast.project(p.points_B(), T_B_C)
        assert np.all((uv > 20) & (uv < [w - 20, h - 20])), (p.target.name, uv.min(axis=0), uv.max(axis=0))
    assert a.max() - a.min() > 150


def test_target_seen_from_behind_is_refused(renderer: CameraRenderer) -> None:
    board = Checkerboard()
    flipped = PlacedTarget(board, make_pose(rot_x(np.pi), [0.0, 0.0, 400.0]))
    with pytest.raises(ValueError, match="behind the plate"):
        renderer.render(np.eye(4), None, targets=[flipped], rng=np.random.default_rng(0))


def test_invalid_targets_are_refused_naming_the_field() -> None:
    with pytest.raises(ValueError, match="inner_corners"):
        Checkerboard(inner_corners=(1, 6))
    with pytest.raises(ValueError, match="square_mm"):
        Checkerboard(square_mm=0.0)
    with pytest.raises(ValueError, match="black_dn"):
        Checkerboard(white_dn=100.0, black_dn=150.0)
    with pytest.raises(ValueError, match="dot_diameter_mm"):
        NinePointTarget(pitch_mm=10.0, dot_diameter_mm=12.0)
    with pytest.raises(ValueError, match="T_B_P"):
        PlacedTarget(Checkerboard(), np.eye(3))


# Squares of about 100, 12 and 8 px; at 1.2 mm/px the lines beside the nearest come within the blur's reach (computed, not taken as 0 or 1).
@pytest.mark.parametrize("mm_per_px", [0.1, 0.8, 1.2])
def test_checkerboard_shading_is_each_cells_coverage_from_its_four_lines(mm_per_px: float) -> None:
    """The board's shading against the general edge model: each cell's coverage from the half-planes of its
    lines (coverage_from_sdf per line), the black cells summed; to the bit, wherever the lines are in reach."""
    from cellctl.sim.edge_coverage import coverage_from_sdf

    board, sigma = Checkerboard(), 0.7
    rng = np.random.default_rng(5)
    n = 50_000
    cols, rows = board.inner_corners
    x = rng.uniform(-board.square_mm - board.border_mm, (cols + 1) * board.square_mm, n)
    y = rng.uniform(-board.square_mm - board.border_mm, (rows + 1) * board.square_mm, n)
    a, d = (rng.uniform(0.6, 1.0, n) * mm_per_px for _ in range(2))
    b, c = (rng.uniform(-0.2, 0.2, n) * mm_per_px for _ in range(2))
    one, zero = np.ones(n), np.zeros(n)

    def beyond(coord: np.ndarray, line_mm: np.ndarray, axis: int) -> np.ndarray:  # coverage of {coord > line}
        g = (-one, zero) if axis == 0 else (zero, -one)
        return coverage_from_sdf(line_mm - coord, *g, (a, b, c, d), sigma)

    s = board.square_mm
    dark = np.zeros(n)
    for ci in range(-1, cols + 2):  # cell ci spans x in [(ci - 1) s, ci s]; black where ci + ri is even on the board
        col = beyond(x, np.full(n, (ci - 1) * s), 0) - beyond(x, np.full(n, ci * s), 0)
        for ri in range(-1, rows + 2):
            if 0 <= ci <= cols and 0 <= ri <= rows and (ci + ri) % 2 == 0:
                dark += col * (beyond(y, np.full(n, (ri - 1) * s), 1) - beyond(y, np.full(n, ri * s), 1))
    expected = board.white_dn - (board.white_dn - board.black_dn) * dark
    np.testing.assert_allclose(board.shade(x, y, (a, b, c, d), sigma), expected, rtol=0, atol=1e-5)  # DN; summed in another order
