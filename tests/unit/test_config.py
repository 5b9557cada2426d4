"""The configuration schema: the shipped files load, bad ones are refused naming the field."""

from __future__ import annotations

import itertools
import tomllib
from pathlib import Path

import numpy as np
import pytest

from cellctl.config import CellConfig, ConfigError, load_config, parse_config
from cellctl.geometry import is_rotation

ROOT = Path(__file__).resolve().parents[2]
SIM_TOML = ROOT / "config" / "sim.toml"


def sim_data() -> dict:
    return tomllib.loads(SIM_TOML.read_text())


def test_sim_toml_loads_and_carries_the_papers_cell() -> None:
    cfg = load_config(SIM_TOML)
    cam = cfg.sim.camera.intrinsics
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (5249.574, 5248.587, 1014.700, 1011.988)
    assert (cam.k1, cam.k2, cam.k3, cam.p1, cam.p2) == (-0.158, -0.0249, 0.0412, -0.0003, 0.0004)
    assert cfg.process.working_distance_mm == 400.0
    assert cfg.sim.robot.repeatability_mm == 0.1
    np.testing.assert_allclose(cfg.sim.laser.r, [43.6839, -40.4931, 90.1015])
    assert abs(np.linalg.norm(cfg.sim.laser.l) - 1.0) < 1e-12


def test_hand_eye_is_reorthonormalised_and_faces_the_wall_with_the_laser() -> None:
    cfg = load_config(SIM_TOML)
    T_H_C = cfg.sim.camera.hand_eye.T_H_C()
    assert is_rotation(T_H_C[:3, :3], tol=1e-12)
    np.testing.assert_allclose(T_H_C[:3, 3], [-54.874, -75.193, 102.960])
    # Optical axis and laser point the same way: the paper's mounting has them 5.3 deg apart.
    assert T_H_C[:3, 2] @ cfg.sim.laser.l > np.cos(np.radians(6))


# Where config/sim.toml departs from the code defaults on purpose (the defaults suit a real cell).
SIM_OVERRIDES = {("plc", "heartbeat_alarm"), ("devices", "laser"), ("devices", "robot")}


def test_code_defaults_equal_the_shipped_sim_toml_but_for_the_sim_overrides() -> None:
    shipped = load_config(SIM_TOML).model_dump()
    defaults = CellConfig().model_dump()
    for section, field in SIM_OVERRIDES:
        assert shipped[section][field] != defaults[section][field]
        shipped[section].pop(field)
        defaults[section].pop(field)
    assert shipped == defaults


@pytest.mark.parametrize(
    ("edit", "field", "hint"),
    [
        (lambda d: d["sim"]["camera"]["intrinsics"].update(fx=-1.0), "sim.camera.intrinsics.fx", "greater than 0"),
        (lambda d: d["sim"]["laser"].update(direction=[2.0, 0.0, 0.0]), "sim.laser.direction", "unit vector"),
        (lambda d: d["sim"]["laser"].update(range_min_mm=500.0), "sim.laser", "range_min_mm"),
        (lambda d: d["process"].update(working_distnce_mm=400.0), "process.working_distnce_mm", "spelling"),
        (lambda d: d["process"]["align"].update(spots_mm=[[0.0, 0.0], [1.0, 1.0]]), "process.align", "at least 3"),
        (lambda d: d["layout"]["opening"].update(up=[1.0, 0.0, 0.0]), "layout.opening", "perpendicular"),
        (lambda d: d["layout"]["opening"].update(corner_radius_mm=150.0), "corner_radius_mm", "reduce corner_radius_mm"),
        (lambda d: d["sim"]["world"].update(corner_radius_mm=10.0), "sim.world.corner_radius_mm", "layout.opening.corner_radius_mm"),
        (lambda d: d["sim"]["robot"].update(reach_mm=2800.0), "sim.robot.reach_mm", "layout.robot.reach_mm"),
        (lambda d: d["sim"]["camera"]["hand_eye"].update(rotation_rows=[[1, 0, 0], [0, 1, 0], [0, 0, 5]]), "hand_eye", "rotation"),
        (lambda d: d.update(mode="production"), "mode", "'sim' or 'hardware'"),
        (
            lambda d: d.setdefault("calibration", {}).setdefault("procedure", {}).setdefault("laser", {}).update(
                wrist_depth_range_mm=[100.0, -100.0]
            ),
            "calibration.procedure.laser",
            "(nearest, farthest)",
        ),
        (
            lambda d: d.setdefault("calibration", {}).setdefault("procedure", {}).setdefault("laser", {}).update(
                wrist_depth_step_mm=0.1
            ),
            "calibration.procedure.laser",
            "at least 1/200 of the range",
        ),
    ],
)
def test_bad_config_is_refused_naming_the_field(edit, field: str, hint: str) -> None:
    data = sim_data()
    edit(data)
    with pytest.raises(ConfigError) as info:
        parse_config(data, "test.toml")
    text = str(info.value)
    assert field in text and hint in text, text


def test_missing_and_malformed_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("mode = \n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(bad)


def test_hardware_example_loads() -> None:
    cfg = load_config(ROOT / "config" / "hardware.example.toml")
    assert cfg.mode == "hardware"
    assert (cfg.devices.laser.kind, cfg.devices.camera.kind, cfg.devices.robot.kind) == ("keyence_lkg", "genicam", "abb")


def test_hardware_mode_refuses_simulated_devices() -> None:
    data = sim_data()
    data["mode"] = "hardware"
    with pytest.raises(ConfigError, match=r"devices \['laser', 'camera', 'robot'\] are simulated"):
        parse_config(data, "x.toml")


def test_laser_arm_stands_span_the_configured_range() -> None:
    lc = CellConfig().calibration.procedure.laser
    stands = lc.wrist_depths_mm()
    assert stands[0] == lc.wrist_depth_range_mm[0] and stands[-1] == lc.wrist_depth_range_mm[1]
    assert len(stands) == 24 and all(abs(b - a - lc.wrist_depth_step_mm) < 1e-9 for a, b in itertools.pairwise(stands))
