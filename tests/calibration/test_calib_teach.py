"""Teaching (paper 4.3 step 1) and the pixel map (paper 4.1) in the twin, on calibrated sensors, against the truth."""

from __future__ import annotations

import asyncio
import functools
import shutil
from pathlib import Path

import numpy as np
import pytest
from calib_test_support import NOW, SEED, board_views, config, scratch, store_with_camera

from cellctl.calibration.calibration_set import CalibrationStore
from cellctl.calibration.compute import Outcome, compute_hand_eye, compute_laser
from cellctl.calibration.compute_recipe import compute_nine_point, compute_teaching
from cellctl.calibration.readiness import check_ready
from cellctl.calibration.recording import record
from cellctl.calibration.compute_recipe import _taught_install
from cellctl.calibration.calibration_set import CalibrationSet
from cellctl.calibration.dataset import Dataset, read_dataset
from cellctl.calibration.errors import CalibrationRefused
from cellctl.sim.commissioning import TwinCommissioning
from cellctl.geometry.pose import make_pose
from cellctl.geometry.rotation import axis_angle_to_matrix
from cellctl.compensate import deviation_in_frame
from cellctl.geometry.rotation import angle_between_vectors
from cellctl.sim.camera_model import CameraModel
from cellctl.sim.image_truth import corner_truth
from cellctl.sim.world import nominal_world


@functools.lru_cache(maxsize=1)
def _taught() -> tuple[CalibrationStore, Outcome, Outcome, dict]:  # type: ignore[type-arg]
    """Camera, hand-eye, laser calibrated in the seeded twin, then teaching and the nine-point map."""
    cfg = config()
    ds_views, dets = board_views()
    store = store_with_camera()
    record(store, compute_hand_eye(ds_views, store.current(), cfg, dets), ds_views, cfg, NOW)

    async def go() -> tuple:  # type: ignore[type-arg]
        twin = TwinCommissioning(cfg, seed=SEED)
        try:
            ds_laser = await twin.collect("laser", None, scratch("laser") / "ds")
            record(store, compute_laser(ds_laser, cfg), ds_laser, cfg, NOW)
            ds_teach = await twin.collect("teaching", store.current(), scratch("teach") / "ds")
            teach = compute_teaching(ds_teach, store.current(), cfg)
            record(store, teach, ds_teach, cfg, NOW)
            ds_nine = await twin.collect("pixel_map", store.current(), scratch("nine") / "ds")
            nine = compute_nine_point(ds_nine, store.current(), cfg)
            record(store, nine, ds_nine, cfg, NOW)
            return teach, nine, ds_teach.manifest["twin_truth"]
        finally:
            await twin.close()

    teach, nine, truth = asyncio.run(go())
    return store, teach, nine, truth



def _taught_dataset(part_name: str, kind: str) -> tuple[CalibrationSet, Dataset]:
    """The commissioned set of :func:`_taught` and the dataset its part ``part_name`` was computed from."""
    cal = _taught()[0].current()
    assert cal is not None
    part = cal.part(part_name)
    assert part is not None and part.dataset is not None
    return cal, read_dataset(part.dataset.path, kind)

def test_teaching_finds_the_workpiece_frame_and_the_template() -> None:
    store, teach, _, truth = _taught()
    v = teach.values
    T0 = np.asarray(v["T0"])
    T_true = np.asarray(truth["T_B_T"])
    # T0 is in the robot's belief frame, so the robot's absolute-accuracy error near the corner
    # (up to 0.5 mm here) is part of this difference; the cycle works in the same belief frame.
    dt, dr = deviation_in_frame(T_true, T0)
    assert np.linalg.norm(dt) < 0.6
    assert np.degrees(np.max(np.abs(dr))) < 0.05
    # C_Pos_0 looks square onto the wall at the working distance (the true flange pose there).
    cfg = config()
    C_true = np.asarray(truth["C_Pos_0_true"])
    T_B_C = C_true @ np.asarray(board_views()[0].manifest["twin_truth"]["T_H_C"])
    world = nominal_world(cfg.sim.world)
    assert np.degrees(angle_between_vectors(T_B_C[:3, 2], world.normal_B)) < 0.05
    depth = float(world.normal_B @ (world.T_B_T[:3, 3] - T_B_C[:3, 3]))
    assert abs(depth - cfg.process.working_distance_mm) < 0.5
    # The template is where the twin's camera truly sees the corner (ideal image).
    ct = corner_truth(CameraModel(cfg.sim.camera.intrinsics), T_B_C, world)
    assert np.hypot(v["u_d"] - ct.corner_undistorted_px[0], v["v_d"] - ct.corner_undistorted_px[1]) < 0.5
    assert abs(np.degrees(v["theta_d"] - ct.edge_angle_rad)) < 0.02
    # The twin's opening shows a paint edge, the wall's edge, a flange and a seal: the template's
    # profiles show them and the record keeps which step the rule picked (the wall's edge, as the
    # corner's agreement with the truth above shows: any other step lies 4 mm or more away).
    fe = teach.quality["feature_edge"]
    assert fe["rule"]["count_from"] == "wall" and fe["rule"]["index"] == 0
    for edge in ("top", "right"):
        steps, picked = fe[edge]["steps"], fe[edge]["feature"]
        assert len(steps) >= 3 and picked is not None
        assert steps[picked]["change_dn"] < 0 and steps[picked]["fraction"] >= fe["rule"]["min_step_fraction"]
        assert any(s["offset_px"] < steps[picked]["offset_px"] - 50 for s in steps)  # the paint edge, outside it
    # g_Pos_0 as an operator leaves it: within the hand-guiding error of the exact install.
    ie = truth["g_Pos_0_install_error"]
    assert max(abs(ie["dx_mm"]), abs(ie["dy_mm"]), abs(ie["dz_mm"])) < 0.3
    assert max(abs(ie["drx_deg"]), abs(ie["dry_deg"]), abs(ie["drz_deg"])) < 0.1
    assert set(teach.inputs) == {"camera", "hand_eye", "laser"}
    # g_Pos_0 is the mean of the configured hand-guided installs, which agreed within their spread.
    installs = teach.quality["g_Pos_0_installs"]
    assert installs["count"] == cfg.calibration.procedure.teach.hand_guided_installs == 3
    assert 0.0 < installs["spread_mm"] < 0.3 and 0.0 < installs["spread_deg"] < 0.1


def _install_dataset(installs: list[np.ndarray]) -> Dataset:
    return Dataset(Path("unused"), {"g_Pos_0_installs": [h.tolist() for h in installs], "g_Pos_0": installs[0].tolist()})


def test_g_pos_0_is_the_mean_install_and_installs_far_apart_are_refused() -> None:
    cfg = config()
    base = make_pose(axis_angle_to_matrix([0.0, np.pi / 2, 0.0]), [1500.0, 200.0, 900.0])
    offsets = ([0.06, 0.0, -0.03], [-0.03, 0.05, 0.0], [-0.03, -0.05, 0.03])
    installs = [base @ make_pose(np.eye(3), o) for o in offsets]
    T0 = make_pose(np.eye(3), [1500.0, 1450.0, 1400.0])  # the window corner, 1.35 m from the flange
    g, info = _taught_install(_install_dataset(installs), cfg, T0)
    assert np.allclose(g, base, atol=1e-9)  # the offsets sum to zero
    assert info["count"] == 3 and abs(info["spread_mm"] - np.linalg.norm(offsets[0])) < 1e-9
    # An install turned 0.03 deg about the corner: the flange moves 0.7 mm, the corner does not.
    turn = axis_angle_to_matrix([0.0, 0.0, np.radians(0.03)])
    about_corner = T0 @ make_pose(turn, [0.0, 0.0, 0.0]) @ np.linalg.inv(T0)
    turned = [*installs[:2], about_corner @ installs[2]]
    assert np.linalg.norm(turned[2][:3, 3] - installs[2][:3, 3]) > 0.6
    g, info = _taught_install(_install_dataset(turned), cfg, T0)
    assert info["spread_mm"] < 0.1 and 0.015 < info["spread_deg"] < 0.03
    # One install 1 mm off: the operator is asked to guide again.
    far = [*installs[:2], base @ make_pose(np.eye(3), [1.0, 0.0, 0.0])]
    with pytest.raises(CalibrationRefused) as err:
        _taught_install(_install_dataset(far), cfg, T0)
    assert err.value.reason == "install_spread" and "guide the glass in again" in str(err.value)
    # A dataset from before repeated installs is one install.
    old = Dataset(Path("unused"), {"g_Pos_0": base.tolist()})
    g, info = _taught_install(old, cfg, T0)
    assert np.allclose(g, base) and info["count"] == 1
    assert info["spread_mm"] < 1e-9 and info["spread_deg"] < 1e-9


def test_nine_point_map_and_pixel_scale_match_the_camera() -> None:
    store, _, nine, _ = _taught()
    cfg = config()
    true_mm_per_px = cfg.process.working_distance_mm / cfg.sim.camera.intrinsics.fx
    amap = np.asarray(nine.values["affine"])
    assert abs(nine.quality["map_mm_per_px"] / true_mm_per_px - 1.0) < 0.003
    assert abs(nine.values["scale_mm_per_px"] / true_mm_per_px - 1.0) < 0.003
    assert abs(nine.quality["map_rotation_deg"]) < 0.05
    assert nine.quality["map_rms_mm"] < 0.1 and len(nine.quality["map_residuals_mm"]) == 9
    # Moving right in the image (u) is moving along T0's x; down (v) along T0's y.
    assert amap[0, 0] > 0 and amap[1, 1] > 0
    assert abs(amap[0, 1]) < 1e-3 and abs(amap[1, 0]) < 1e-3
    # Every part present, computed from the current ones, in date: the cell may produce (reading the wall as taught).
    assert check_ready(store.current(), NOW) == [] and check_ready(store.current(), NOW, config=config()) == []
    assert store.current().part("teaching").values.wall_read.mode == "stop_and_go"  # type: ignore[union-attr]


def test_teaching_for_the_cycle_on_the_move_reads_along_the_sweep_and_takes_the_walls_offset_at_its_corners(
    tmp_path: Path,
) -> None:
    # The cycle on the move fits the wall's normal along its path and its offset where the flange stands, at the
    # path's corners; the robot's accuracy differs between the two. Teaching measures the same way, so it cancels.
    store = _taught()[0]
    base = config()
    align = base.process.align.model_copy(update={"mode": "on_the_fly"})
    cfg = base.model_copy(update={"process": base.process.model_copy(update={"align": align})})

    async def go() -> Dataset:
        twin = TwinCommissioning(cfg, seed=SEED)
        try:
            return await twin.collect("teaching", store.current(), scratch("teach-on-the-move") / "ds")
        finally:
            await twin.close()

    ds = asyncio.run(go())
    spots = ds.manifest["spots"]
    along = align.sweep.points_along_mm()
    stops = [0, 16, 29, 42]  # every 100 mm along the path's 1560, 1260 and 1260 mm legs; back at the second corner
    assert len(spots) == len(along) and [k for k, s in enumerate(spots) if s.get("stop")] == stops
    assert [along[k] for k in stops] == [tuple(c) for c in align.sweep.path_mm]
    teach = compute_teaching(ds, store.current(), cfg)
    assert teach.quality["offset_from_stops"] == 4
    assert "its distance at the sweep's 4 stops" in teach.summary[0]
    plane = teach.detail[0].wall.plane
    r, l = store.current().laser_ray()  # noqa: E741
    points = np.array([np.asarray(s["T_B_H"]) @ np.r_[r + s["distance_mm"] * l, 1.0] for s in spots])[:, :3]
    corners = points[stops] @ plane.normal
    assert plane.offset == pytest.approx(float(corners.mean()), abs=1e-6)  # eq. 2 at the corners, not over the path
    assert abs(plane.offset - float((points @ plane.normal).mean())) > 1e-4  # which differs here
    assert np.degrees(angle_between_vectors(plane.normal, nominal_world(cfg.sim.world).normal_B)) < 0.05
    # The teaching records how and where it read the wall; a cell back to reading standing must teach again.
    assert teach.values["wall_read"] == {"mode": "on_the_fly", "spots_mm": [list(p) for p in along]}
    shutil.copytree(store.root, tmp_path / "set")
    mine = CalibrationStore(tmp_path / "set")
    record(mine, teach, ds, cfg, NOW)
    teaching = lambda c: [p for p in check_ready(mine.current(), NOW, config=c) if p.startswith("teaching")]  # noqa: E731
    assert teaching(cfg) == []  # (the nine-point map is now stale: it comes after the teaching)
    (problem,) = teaching(base)
    assert problem.startswith("teaching: taught reading the wall along process.align.sweep.path_mm") and "`cellctl teach`" in problem


def test_a_shot_setting_changed_after_teaching_stops_production_naming_the_setting() -> None:
    """T0 is the feature seen at the taught shooting pose: a new working distance, corner radius or aim needs a new teaching."""
    store, _, _, _ = _taught()
    cfg = config()
    assert check_ready(store.current(), NOW, config=cfg) == []

    def teaching(c: object) -> list[str]:
        return [p for p in check_ready(store.current(), NOW, config=c) if p.startswith("teaching")]  # type: ignore[arg-type]

    nearer = cfg.model_copy(update={"process": cfg.process.model_copy(update={"working_distance_mm": 380.0})})
    (problem,) = teaching(nearer)
    assert "process.working_distance_mm was 400 mm, now 380" in problem and "`cellctl teach`" in problem, problem
    opening = cfg.layout.opening.model_copy(update={"corner_radius_mm": 60.0})
    rounder = cfg.model_copy(update={"layout": cfg.layout.model_copy(update={"opening": opening})})
    (problem,) = teaching(rounder)
    assert f"corner_radius_mm ([layout.opening], or recipe {cfg.default_recipe}'s [process.recipes.opening]) was" in problem
    assert "the shot measured the corner, now the arc" in problem, problem
