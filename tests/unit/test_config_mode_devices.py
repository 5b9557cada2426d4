"""A configuration in mode "sim" (the default when the line is left out) that names a real device is refused at load,
naming the device's field and both fixes: mode = "hardware" (whose security checks then apply) or the twin's kinds.
Without this, a config with the real robot, laser and camera ran as "sim" and skipped every hardware security check."""

from __future__ import annotations

import asyncio
import tomllib
from pathlib import Path
from typing import Any

import pytest
from shared_support import run_cli

from cellctl.config import load_config
from cellctl.config.devices import DevicesConfig
from cellctl.service.compose import ServiceError

ROOT = Path(__file__).resolve().parents[2]
HARDWARE = (ROOT / "config" / "hardware.example.toml").read_text()
REAL = {
    "laser": {"kind": "keyence_lkg", "port": "/dev/lkg", "dialect": "LK-G5001", "display_unit": "0.001mm",
              "reference_distance_mm": 350.0, "displacement_positive": "away_from_head"},
    "camera": {"kind": "genicam", "cti_path": "/opt/vendor/producer.cti"},
    "robot": {"kind": "abb", "host": "127.0.0.1"},
}  # fmt: skip
TWIN_KINDS = 'laser "sim" or "sim_keyence_lkg", camera "sim", robot "sim" or "sim_abb"'


def _sim_toml_with(device: str, section: dict[str, Any]) -> str:
    """config/sim.toml with one [devices.<device>] table replaced by ``section`` (its mode line kept: "sim")."""
    lines = (ROOT / "config" / "sim.toml").read_text().splitlines()
    start = lines.index(f"[devices.{device}]")
    end = next(k for k in range(start + 1, len(lines)) if lines[k].startswith("["))
    table = [f"[devices.{device}]"] + [f"{k} = {v!r}".replace("'", '"') for k, v in section.items()]
    return "\n".join(lines[:start] + table + lines[end:]) + "\n"


def _check(capsys: pytest.CaptureFixture[str], tmp_path: Path, text: str) -> tuple[int, str, str]:
    cfg = tmp_path / "cell.toml"
    cfg.write_text(text)
    return run_cli(capsys, "config", "check", "--config", str(cfg))


@pytest.mark.parametrize("device", ["laser", "camera", "robot"])
def test_a_real_device_in_mode_sim_is_refused_naming_the_field_and_the_fix(
    device: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    text = _sim_toml_with(device, REAL[device])
    assert tomllib.loads(text)["mode"] == "sim" and tomllib.loads(text)["devices"][device] == REAL[device]
    rc, out, err = _check(capsys, tmp_path, text)
    assert rc == 2 and out == "" and "Traceback" not in err, out + err
    assert f'devices.{device}.kind = "{REAL[device]["kind"]}" names a real device' in err, err
    assert 'set mode = "hardware"' in err and "security checks then apply" in err and TWIN_KINDS in err, err


def test_the_hardware_example_without_its_mode_line_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The reviewer's case: the real drivers, the mode line left out, a token written in the file, OPC UA None."""
    text = HARDWARE.replace('mode = "hardware"\n', "", 1).replace('security_policies = ["Basic256Sha256_SignAndEncrypt"]',
                                                                  'security_policies = ["None"]')  # fmt: skip
    assert "mode =" not in text.split("[", 1)[0]
    rc, _, err = _check(capsys, tmp_path, text)
    assert rc == 2, err
    real = 'devices.laser.kind = "keyence_lkg", devices.camera.kind = "genicam", devices.robot.kind = "abb" name real devices'
    assert real in err and '(the default when mode is left out)' in err, err


def test_the_shipped_configurations_still_load() -> None:
    sim = load_config(ROOT / "config" / "sim.toml")  # the drivers on their protocol fakes: sim_keyence_lkg, sim_abb
    assert sim.mode == "sim" and (sim.devices.laser.kind, sim.devices.robot.kind) == ("sim_keyence_lkg", "sim_abb")
    assert load_config(ROOT / "config" / "hardware.example.toml").mode == "hardware"


def test_the_simulated_root_builds_no_real_driver_from_a_copy_past_validation(tmp_path: Path) -> None:
    """A configuration copied without validation (model_copy) keeps a real robot: the simulated root refuses it
    before it builds anything, rather than driving a real controller or silently the twin's robot."""
    from cellctl.service.simulated import build_sim_service

    config = load_config(ROOT / "config" / "sim.toml")
    devices = DevicesConfig.model_validate({"laser": {"kind": "sim"}, "robot": REAL["robot"]})
    copied = config.model_copy(update={"devices": devices})
    with pytest.raises(ServiceError, match=r"devices \['robot'\] are real devices.*set mode = \"hardware\""):
        asyncio.run(build_sim_service(copied, workdir=tmp_path))
    assert not (tmp_path / "var").exists()  # nothing was made
