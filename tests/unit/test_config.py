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
SIM_OVERRIDES = {("plc", "heartbeat_alarm"), ("devices", "laser"), ("devices", "robot"),
                 ("opcua", "security_policies"), ("opcua", "allow_anonymous"),  # the demo also offers None and anonymous
                 ("process", "recipes"),  # the simulated line installs two window types; the default is one
                 ("process", "motion")}  # after the release the twin's robot goes faster; by default as with the glass


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
        (lambda d: (d["layout"]["opening"].update(corner_radius_mm=150.0), d["sim"]["world"].update(corner_radius_mm=150.0),
                    d.setdefault("vision", {}).update(shot_aim_mm=[0.0, 0.0])), "vision.shot_aim_mm", "arc spans"),
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


# -- issue 15: where a cell's tokens come from, and files that are no configuration ---------------

STRONG = "Vq3-xK9_pL2mZ8rT5wY1nB7cD4fG6hJ0"


def hardware_text() -> str:
    """config/hardware.example.toml with every address on loopback (it is loaded here, never served)."""
    text = (ROOT / "config" / "hardware.example.toml").read_text()
    return text.replace('"192.168.125.1"', '"127.0.0.1"').replace('"0.0.0.0"', '"127.0.0.1"')


def hardware_data() -> dict:
    return tomllib.loads(hardware_text())


@pytest.mark.parametrize(
    ("value", "why"),
    [
        ("sim-operator-token-change-me", "default or a placeholder"),
        ("replace-with-a-long-random-operator-token", "default or a placeholder"),
        ("our-line-token-CHANGEME-2024", "default or a placeholder"),
        ("an-example-token-for-cell-1", "default or a placeholder"),
        ("short-token", "fewer than 16"),
        ("aaaaaaaaaaaaaaaaaaaaaaaa", "different characters"),
        ("abcdefgh ijklmnopqrst", "whitespace"),
    ],
)
def test_a_weak_token_is_refused_by_the_one_rule(value: str, why: str) -> None:
    from cellctl.config.api import token_weakness

    assert why in (token_weakness(value) or "")
    assert token_weakness(STRONG) is None


def test_hardware_mode_refuses_a_config_that_names_no_token() -> None:
    data = hardware_data()
    del data["api"]["tokens"]
    with pytest.raises(ConfigError) as info:
        parse_config(data, "cell.toml")
    assert "api.tokens: no token is configured" in str(info.value) and "token_env" in str(info.value)
    data.pop("api")
    with pytest.raises(ConfigError, match="api.tokens: no token is configured"):
        parse_config(data, "cell.toml")


def test_hardware_mode_refuses_a_token_written_in_the_config() -> None:
    data = hardware_data()
    data["api"]["tokens"][1] = {"name": "line-integrator", "token": STRONG}
    with pytest.raises(ConfigError) as info:
        parse_config(data, "cell.toml")
    text = str(info.value)
    assert "api.tokens.1.token" in text and "token_env" in text and "token_file" in text
    data["api"]["tokens"][1] = {"name": "line-integrator", "token_file": "tokens/integrator"}
    with pytest.raises(ConfigError, match=r"api.tokens.1.token_file: give an absolute path"):
        parse_config(data, "cell.toml")
    # The simulated cell keeps its token in the file (the default token is the sim's).
    assert parse_config(sim_data()).api.tokens[0].token == "sim-operator-token-change-me"


def test_serving_reads_every_token_first_and_names_what_is_missing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "cell.toml"
    path.write_text(hardware_text())
    monkeypatch.delenv("CELLCTL_TOKEN", raising=False)
    monkeypatch.setenv("CELLCTL_TOKEN_INTEGRATOR", "replace-with-a-long-random-integrator-token")
    assert load_config(path).mode == "hardware"  # commands that only talk to the service need no tokens
    with pytest.raises(ConfigError) as info:
        load_config(path, read_tokens=True)
    text = str(info.value)
    assert "environment variable CELLCTL_TOKEN is not set" in text and "deploy/cellctl.env.example" in text
    assert "CELLCTL_TOKEN_INTEGRATOR is refused: it is a shipped default or a placeholder" in text
    assert "opcua.users 'mes': password_env: environment variable CELLCTL_OPCUA_MES_PASSWORD is not set" in text
    monkeypatch.setenv("CELLCTL_TOKEN", STRONG)
    monkeypatch.setenv("CELLCTL_TOKEN_INTEGRATOR", STRONG[::-1])
    monkeypatch.setenv("CELLCTL_OPCUA_MES_PASSWORD", STRONG[1:] + "Q")
    cfg = load_config(path, read_tokens=True)
    assert cfg.api.secrets() == (("operator", STRONG), ("line-integrator", STRONG[::-1]))


def test_a_token_file_must_exist_hold_a_token_and_be_private(tmp_path: Path) -> None:
    from cellctl.config.api import ApiToken, TokenUnavailable

    f = tmp_path / "operator.token"
    token = ApiToken(name="operator", token_file=f)
    for prepare, why in [
        (lambda: None, "does not exist"),
        (lambda: (f.write_text("\n"), f.chmod(0o600)), "is empty"),
        (lambda: f.write_text("sim-operator-token-change-me\n"), "default or a placeholder"),
        (lambda: (f.write_text(STRONG), f.chmod(0o644)), "chmod 600"),
        (lambda: (f.unlink(), f.mkdir()), "not a regular file"),
    ]:
        prepare()
        with pytest.raises(TokenUnavailable, match=why) as info:
            token.secret()
        assert "api.tokens 'operator': token_file" in str(info.value)
    f.rmdir()
    f.write_text(STRONG + "\n")
    f.chmod(0o600)
    assert token.secret() == STRONG


def test_a_token_names_exactly_one_source() -> None:
    data = sim_data()
    data["api"]["tokens"] = [{"name": "operator", "token_env": "CELLCTL_TOKEN", "token_file": "/etc/cellctl/operator.token"}]
    with pytest.raises(ConfigError, match="give exactly one of token_env, token_file or token"):
        parse_config(data, "x.toml")


def test_a_directory_or_a_file_that_is_not_utf8_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="is a directory"):
        load_config(tmp_path)
    latin1 = tmp_path / "latin1.toml"
    latin1.write_bytes('cell_id = "cell-1"\n# Zelle für Seitenfenster\n'.encode("latin-1"))
    with pytest.raises(ConfigError, match=r"not UTF-8 text \(byte 0xfc on line 2\)"):
        load_config(latin1)
    with pytest.raises(ConfigError, match="not a regular file"):
        load_config("/dev/null")


@pytest.mark.parametrize("command", [["status"], ["serve"], ["calibrate", "status"]])
def test_the_cli_refuses_such_a_config_with_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: list[str]
) -> None:
    from cellctl.cli import main

    binary = tmp_path / "cell.toml"
    binary.write_bytes(b"\xff\xfe\x00m\x00o\x00d\x00e")
    for bad, why in ((tmp_path, "is a directory"), (binary, "not UTF-8")):
        assert main(["--config", str(bad), *command]) == 2
        err = capsys.readouterr().err
        assert "configuration refused" in err and why in err and "Traceback" not in err


def test_serve_refuses_an_unset_token_env_before_it_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from cellctl.cli import main

    text = SIM_TOML.read_text()
    old = 'token = "sim-operator-token-change-me"'
    assert text.count(old) == 1
    path = tmp_path / "cell.toml"  # config/sim.toml (loopback only) with its token from an unset variable
    path.write_text(text.replace(old, 'token_env = "CELLCTL_TEST_TOKEN_NEVER_SET"'))
    monkeypatch.delenv("CELLCTL_TEST_TOKEN_NEVER_SET", raising=False)
    assert main(["--config", str(path), "serve", "--workdir", str(tmp_path)]) == 2
    out, err = capsys.readouterr()
    assert "serving on" not in out and "CELLCTL_TEST_TOKEN_NEVER_SET is not set" in err
    assert not (tmp_path / "var").exists()  # nothing was built: no database, no images
