"""The twin's configuration: config/sim.toml loads as the paper's cell; bad values are refused by name."""

from __future__ import annotations

import copy
import math
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cellctl.config import ConfigError, load_config, parse_config
from cellctl.config.sim import GlassConfig, LaserSimConfig, RobotSimConfig, SimConfig, WorldConfig
from cellctl.geometry.pose import check_pose

SIM_TOML = Path(__file__).resolve().parents[2] / "config" / "sim.toml"


def _document() -> dict[str, Any]:
    return tomllib.loads(SIM_TOML.read_text(encoding="utf-8"))


def _with(path: str, value: Any) -> dict[str, Any]:
    doc = copy.deepcopy(_document())
    node = doc
    *parents, leaf = path.split(".")
    for key in parents:
        node = node.setdefault(key, {})
    node[leaf] = value
    return doc


def test_sim_toml_is_the_paper_cell() -> None:
    sim = load_config(SIM_TOML).sim
    # The file spells out the schema's defaults for the twin's own sections.
    assert sim.world == WorldConfig()
    assert sim.robot == RobotSimConfig()
    assert sim.laser == LaserSimConfig()
    assert sim.glass == GlassConfig()
    assert sim.seed == SimConfig().seed and sim.time_scale == SimConfig().time_scale
    # Paper section 5.1: IRB 7600-325 reach 3.1 m, repeatability 0.1 mm; LK-G500 250-450 mm, +-0.02 %.
    assert sim.robot.reach_mm == 3100.0 and sim.robot.repeatability_mm == 0.1
    assert (sim.laser.range_min_mm, sim.laser.range_max_mm) == (250.0, 450.0)
    assert math.isclose(sim.laser.linearity_fraction_fs * sim.laser.full_scale_mm, 0.04)
    check_pose(sim.robot.T_B_H_home(), "home")
    check_pose(sim.glass.T_H_G(), "T_H_G")


@pytest.mark.parametrize(
    ("path", "value", "named"),
    [
        ("sim.robot.repeatability_mm", -0.1, "sim.robot.repeatability_mm"),
        ("sim.robot.absolute_accuracy_mm", float("nan"), "sim.robot.absolute_accuracy_mm"),
        ("sim.robot.absolute_accuracy_deg", 5.0, "sim.robot.absolute_accuracy_deg"),
        ("sim.robot.max_speed_mm_s", 0.0, "sim.robot.max_speed_mm_s"),
        ("sim.robot.accuracy_wavelength_mm", 10.0, "sim.robot.accuracy_wavelength_mm"),
        ("sim.robot.home_position_mm", [5000.0, 0.0, 1600.0], "home_position_mm"),
        ("sim.robot.min_reach_mm", 3200.0, "min_reach_mm"),
        ("sim.robot.reach_centre_mm", [0.0, 780.0], "sim.robot.reach_centre_mm"),
        ("sim.robot.top_speed", 2000.0, "sim.robot.top_speed"),
        ("sim.laser.noise_mm", -0.002, "sim.laser.noise_mm"),
        ("sim.laser.linearity_fraction_fs", float("inf"), "sim.laser.linearity_fraction_fs"),
        ("sim.laser.no_return_status", "nothing", "sim.laser.no_return_status"),
        ("sim.laser.range_min_mm", 500.0, "range_min_mm"),
        ("sim.glass.rotation_xyz_fixed_deg", [0.0, 1.0], "sim.glass.rotation_xyz_fixed_deg"),
        ("sim.world.posture_rotation_deg", [2.0, -1.0, 2.0], "posture ranges"),
        ("sim.seed", -3, "sim.seed"),
        ("sim.time_scale", -1.0, "sim.time_scale"),
    ],
)
def test_invalid_values_are_refused_naming_the_field(path: str, value: Any, named: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_config(_with(path, value), "sim.toml")
    assert named in str(info.value)


def test_error_sources_can_each_be_switched_off() -> None:
    doc = _document()
    for key in ("repeatability_mm", "repeatability_orientation_deg", "absolute_accuracy_mm", "absolute_accuracy_deg"):
        doc["sim"]["robot"][key] = 0.0
    for key in ("linearity_fraction_fs", "noise_mm"):
        doc["sim"]["laser"][key] = 0.0
    sim = parse_config(doc).sim
    assert sim.robot.repeatability_mm == 0.0 and sim.laser.noise_mm == 0.0


def test_glass_rotation_enters_T_H_G() -> None:
    glass = GlassConfig(rotation_xyz_fixed_deg=(0.0, 0.0, 90.0))
    R = glass.T_H_G()[:3, :3]
    np.testing.assert_allclose(R @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)
