"""Board plans (camera intrinsics, hand-eye) on a binned camera, and plans too short for their gate.

calibration.procedure.camera.margin_px is stated for a 2048 px wide image and scales with the camera: the hardware
tests' camera (TLSimu, 512 x 512 px: the data sheet's lens binned 4 x 4) must plan as many views as the gates need,
each showing the whole board (OpenCV's projectPoints is the judge). A plan with fewer views than its computation
accepts is refused before anything moves, in a dry run and in a job, naming the numbers and the settings.
"""

from __future__ import annotations

import asyncio
import tomllib
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from service_test_support import AUTH, ROOT, api_client, job_ended, running_service, sim_config

from cellctl.commissioning.plans import PlanError, nominal_T0, plan_board
from cellctl.config import CellConfig, parse_config
from cellctl.geometry.pose import pose_in_plane

BINNED_FX = 5250.0 / 4  # tests/hardware/test_hardware_mode_process.py: the data sheet's lens binned 4 x 4


def binned_config(**camera_procedure: Any) -> CellConfig:
    """config/hardware.example.toml with sim.toml's [layout] and TLSimu's 512 x 512 px camera, as tests/hardware builds it."""
    data = tomllib.loads((ROOT / "config" / "hardware.example.toml").read_text())
    data["layout"] = tomllib.loads((ROOT / "config" / "sim.toml").read_text())["layout"]
    data["layout"]["camera"].update(width_px=512, height_px=512, fx=BINNED_FX, fy=BINNED_FX, cx=256.0, cy=256.0)
    data.setdefault("vision", {})["roi"] = {"x_px": 0, "y_px": 0, "width_px": 512, "height_px": 512}
    data["vision"].setdefault("gap", {}).update(start_px=110.0, length_px=140.0, min_points=60)  # the 2048 px window, binned 4 x 4
    if camera_procedure:
        data["calibration"].setdefault("procedure", {}).setdefault("camera", {}).update(camera_procedure)
    return parse_config(data, "hardware.example.toml, binned camera (test)")


def _board_inside_px(config: CellConfig, poses: list[Any]) -> float:
    """OpenCV: how far inside the 512 x 512 image the printed board (squares and border) stays over all views (px)."""
    cc = config.calibration.procedure.camera
    (cols, rows), s, m = cc.board.inner_corners, cc.board.square_mm, cc.board.border_mm
    plate = np.array([[-s - m, -s - m, 0], [cols * s + m, -s - m, 0], [cols * s + m, rows * s + m, 0], [-s - m, rows * s + m, 0]])
    T_B_P = pose_in_plane(nominal_T0(config), cc.board_on_wall_mm)
    pts_B = (T_B_P @ np.c_[plate, np.ones(4)].T).T[:, :3]
    K = np.array([[BINNED_FX, 0.0, 256.0], [0.0, BINNED_FX, 256.0], [0.0, 0.0, 1.0]])  # the lens as typed, no distortion
    T_H_C = config.layout.camera_mount.T_H_C()
    inside = []
    for X in poses:
        T_C_B = np.linalg.inv(X @ T_H_C)
        pc = (T_C_B @ np.c_[pts_B, np.ones(4)].T).T[:, :3]
        assert (pc[:, 2] > 0).all()
        uv = cv2.projectPoints(pc.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, np.zeros(5))[0].reshape(-1, 2)
        inside.append(min(uv.min(), 511.0 - uv.max()))
    return float(min(inside))


def test_the_binned_512_px_camera_plans_the_views_its_gates_need_each_showing_the_board() -> None:
    cfg = binned_config()
    pc = cfg.calibration.procedure
    for procedure, need in (("camera", pc.camera.min_views), ("hand_eye", pc.hand_eye.min_views)):
        plan = plan_board(cfg, procedure=procedure)
        assert len(plan.poses) >= need, f"{procedure}: {len(plan.poses)} views planned, its gate needs {need}"
        assert len(plan.poses) == pc.camera.n_views  # as on the 2048 px camera with the same optics
        # margin_px 30 at 2048 px is 7.5 px at 512 px: every view keeps the board at least that far inside
        assert _board_inside_px(cfg, plan.poses) >= 7.5 - 1e-6


def test_a_plan_short_of_its_gate_is_refused_naming_the_numbers_and_a_views_that_plans_enough() -> None:
    cfg = binned_config(margin_px=120.0)  # 30 px on this camera: the band that left 6 views before the margin scaled
    with pytest.raises(PlanError) as err:
        plan_board(cfg)
    text = str(err.value)
    assert getattr(err.value, "reason", None) == "too_few_views" and "calibration.procedure.camera.min_views" in text, text
    assert "only 6 of the 12 board views" in text and "at least 8" in text, text
    assert "calibration.procedure.camera.margin_px (120 px stated for a 2048 px wide image, 30 px on this 512 px" in text, text
    assert "distance_mm" in text and "n_views" in text and "Nothing moved" in text, text
    ask = int(text.split("--views ")[1].split()[0])  # the --views it offers does plan enough
    assert len(plan_board(cfg, views=ask).poses) >= 8
    # hand-eye's own gate: calibration.procedure.hand_eye.min_views (6) is met by the same 6 views
    assert len(plan_board(cfg, procedure="hand_eye").poses) == 6
    with pytest.raises(PlanError, match=r"only 5 of the 12 .* at least 6 \(calibration.procedure.hand_eye.min_views\)"):
        plan_board(binned_config(margin_px=130.0), procedure="hand_eye")
    # too few asked for: the refusal says how many are needed
    with pytest.raises(PlanError, match=r"5 board views are asked for, and the calibration needs at least 8 .*--views 8"):
        plan_board(binned_config(), views=5)


async def test_a_job_whose_plan_is_short_is_refused_before_the_robot_moves(tmp_path: Path) -> None:
    cfg = sim_config(**{"calibration": {"source": "set", "auto_calibrate_in_sim": False}, "sim.operator": {"answers": "actions"},
                        "plc": {"enabled": False}, "calibration.procedure.camera": {"margin_px": 120.0}})  # fmt: skip
    async with running_service(tmp_path, cfg) as service, api_client(service) as client:
        arm = service.extras["fakes"]["robot"].robot  # the ABB fake's controller: the truth about motion
        r = await client.post("/jobs/plan", json={"procedure": "camera", "options": {}}, headers=AUTH)
        assert r.status_code == 422, r.text
        detail = r.json()["detail"]
        assert "too_few_views" in detail and "only 6 of the 12" in detail and "margin_px" in detail and "--views" in detail, detail
        assert (await client.post("/commands/clear", headers=AUTH)).status_code == 200
        for _ in range(200):
            if (await client.get("/status")).json()["state"] == "STOPPED":
                break
            await asyncio.sleep(0.02)
        began: list[Any] = []
        begin = arm.begin_motion
        arm.begin_motion = lambda *a, **k: began.append(a) or begin(*a, **k)  # every move the controller starts
        r = await client.post("/jobs", json={"procedure": "camera", "options": {}}, headers=AUTH)
        assert r.status_code == 201, r.text
        job = await job_ended(client, r.json()["id"])
        assert job["state"] == "refused" and job["error"].startswith("too_few_views: only 6 of the 12"), job
        assert "calibration.procedure.camera.margin_px" in job["error"] and "--views" in job["error"], job
        assert not job.get("progress") and job["dataset"] is None, job  # no pose visited, nothing collected
        assert began == [] and not arm.moving
        entries = await service.store.audit_entries(limit=100)
        assert not [e for e in entries if e.action == "job.prompt"]  # nobody was asked to place a board
