"""The error-source switches: each one really removes its source from the twin, and only that one."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cellctl.bench.sources import ERROR_SOURCES, BenchSettingsError, parse_off, run_config
from cellctl.config import load_config
from cellctl.geometry.pose import make_pose
from cellctl.sim.camera import CameraRenderer
from cellctl.sim.cell import SimCell
from cellctl.sim.image_truth import camera_pose_seeing_corner

ROOT = Path(__file__).resolve().parents[2]
BASE = load_config(ROOT / "config" / "sim.toml")


def _cell(tmp_path: Path, off: frozenset[str] | tuple[str, ...]) -> SimCell:
    return SimCell(run_config(BASE, workdir=tmp_path, seed=7, off=off).sim)


def _spot_pose(cell: SimCell) -> np.ndarray:
    """A flange pose whose laser beam hits the wall about 350 mm away (the camera square to the wall)."""
    T = cell.world().T_B_T
    T_B_C = T @ make_pose(np.eye(3), [-300.0, -200.0, -400.0])
    return T_B_C @ np.linalg.inv(cell.T_H_C)


def test_parse_off_names_all_and_refusals() -> None:
    assert parse_off(None) == frozenset()
    assert parse_off(" laser_noise , image_noise ") == {"laser_noise", "image_noise"}
    assert parse_off("all") == set(ERROR_SOURCES)
    with pytest.raises(BenchSettingsError, match="unknown error source.*lazer_noise.*known: laser_noise"):
        parse_off("lazer_noise")


def test_run_config_sets_the_run_and_refuses_bad_settings(tmp_path: Path) -> None:
    cfg = run_config(BASE, workdir=tmp_path, seed=3, off=("robot_accuracy",), calibration="data", time_scale=0.0)
    assert cfg.sim.seed == 3 and cfg.sim.time_scale == 0.0
    assert cfg.sim.robot.absolute_accuracy_mm == 0.0 and cfg.sim.robot.absolute_accuracy_deg == 0.0
    assert cfg.sim.robot.repeatability_mm == BASE.sim.robot.repeatability_mm  # only the named source
    assert cfg.plc.enabled is False
    assert cfg.calibration.source == "set" and Path(cfg.calibration.directory).is_relative_to(tmp_path.resolve())
    assert Path(cfg.store.path).is_relative_to(tmp_path.resolve())
    assert {cfg.devices.laser.kind, cfg.devices.camera.kind, cfg.devices.robot.kind} == {"sim"}
    assert run_config(BASE, workdir=tmp_path, seed=3, calibration="oracle").calibration.source == "oracle"
    with pytest.raises(BenchSettingsError, match="unknown error source"):
        run_config(BASE, workdir=tmp_path, seed=1, off=("gravity",))
    with pytest.raises(BenchSettingsError, match="--calibration"):
        run_config(BASE, workdir=tmp_path, seed=1, calibration="guess")  # type: ignore[arg-type]
    hardware = BASE.model_copy(update={"mode": "hardware"})
    with pytest.raises(BenchSettingsError, match="simulated cell"):
        run_config(hardware, workdir=tmp_path, seed=1)


def test_laser_noise_switch_leaves_only_the_linearity_curve(tmp_path: Path) -> None:
    on, off = _cell(tmp_path, ()), _cell(tmp_path, ("laser_noise",))
    X = _spot_pose(off)
    T_true = off.execute(X)
    truth = off.laser_model.true_distance(T_true, off.world())
    assert truth is not None and 250.0 < truth < 450.0
    expected = truth + float(off.laser_model.linearity_error(truth))
    readings = [off.laser_reading()[1] for _ in range(5)]
    assert readings == pytest.approx([expected] * 5, abs=1e-12)
    T_on = on.execute(X)
    noisy = np.array([on.laser_reading()[1] for _ in range(20)]) - on.laser_model.true_distance(T_on, on.world())
    assert np.std(noisy) > 0.5 * BASE.sim.laser.noise_mm  # the source is there when not switched off


def test_laser_linearity_switch(tmp_path: Path) -> None:
    d = np.linspace(260.0, 440.0, 7)
    assert np.all(_cell(tmp_path, ("laser_linearity",)).laser_model.linearity_error(d) == 0.0)
    assert np.max(np.abs(_cell(tmp_path, ()).laser_model.linearity_error(d))) > 1e-3


def test_robot_switches(tmp_path: Path) -> None:
    X = _spot_pose(_cell(tmp_path, ()))
    still = _cell(tmp_path, ("robot_repeatability",)).robot_model
    assert np.allclose(still.draw_noise(), np.eye(4), atol=0.0)
    exact = _cell(tmp_path, ("robot_accuracy",)).robot_model
    assert np.allclose(exact.deform(X), X, atol=1e-12)
    both = _cell(tmp_path, ("robot_accuracy", "robot_repeatability"))
    assert np.allclose(both.execute(X), X, atol=1e-9)  # the flange goes exactly where it is told
    full = _cell(tmp_path, ()).robot_model
    assert np.linalg.norm(full.deform(X)[:3, 3] - X[:3, 3]) > 1e-3
    assert np.linalg.norm(full.draw_noise()[:3, 3]) > 0.0


def test_image_noise_switch(tmp_path: Path) -> None:
    def two_frames(off: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
        sim = run_config(BASE, workdir=tmp_path, seed=7, off=off).sim
        cell = SimCell(sim)
        renderer = CameraRenderer(sim.camera.intrinsics, sim.camera.render)
        pose = camera_pose_seeing_corner(renderer.camera, cell.world(), (1014.7, 1012.0))
        a = renderer.render(pose, cell.world(), rng=np.random.default_rng(1)).image
        b = renderer.render(pose, cell.world(), rng=np.random.default_rng(2)).image
        return a, b

    a, b = two_frames(("image_noise",))
    assert np.array_equal(a, b)
    a, b = two_frames(())
    assert np.count_nonzero(a != b) > a.size // 10
