"""What a hardware cell refuses in [opcua] beside anonymous access and policy None: no trusted client folder
(the server would then trust any client certificate) and the sign-only policy (results and commands in clear),
as the README's Plant integration section says; the simulated cell keeps both defaults."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import pytest
from shared_support import run_cli

from cellctl.config import ConfigError, parse_config

ROOT = Path(__file__).resolve().parents[2]
HARDWARE = ROOT / "config" / "hardware.example.toml"
SIM = ROOT / "config" / "sim.toml"


def _hardware() -> dict[str, Any]:
    return tomllib.loads(HARDWARE.read_text(encoding="utf-8"))


def test_the_shipped_hardware_example_names_its_trusted_clients_and_passes() -> None:
    data = _hardware()
    assert data["mode"] == "hardware" and data["opcua"]["trusted_clients"] == "/etc/cellctl/opcua/trusted"
    assert parse_config(data, "hardware.example.toml").opcua.trusted_clients == Path("/etc/cellctl/opcua/trusted")


def test_a_hardware_cell_without_trusted_clients_is_refused_naming_the_folder_to_give() -> None:
    data = _hardware()
    del data["opcua"]["trusted_clients"]
    with pytest.raises(ConfigError) as err:
        parse_config(data, "hardware without trusted_clients")
    text = str(err.value)
    assert "opcua.trusted_clients: not set, so the server trusts every client certificate" in text, text
    assert "the folder of the client certificates the cell accepts" in text, text
    data["opcua"]["enabled"] = False  # no server, nothing to trust
    parse_config(data, "hardware, OPC UA off")


def test_the_simulated_cell_may_trust_any_client_certificate() -> None:
    data = tomllib.loads(SIM.read_text(encoding="utf-8"))
    assert "trusted_clients" not in data["opcua"] and data["opcua"]["enabled"] is True
    assert parse_config(data, "sim.toml").opcua.trusted_clients is None


@pytest.mark.parametrize("policies", [["Basic256Sha256_Sign"], ["Basic256Sha256_SignAndEncrypt", "Basic256Sha256_Sign"]])
def test_a_hardware_cell_refuses_the_sign_only_policy(policies: list[str]) -> None:
    data = _hardware()
    data["opcua"]["security_policies"] = policies
    with pytest.raises(ConfigError) as err:
        parse_config(data, "hardware, sign only")
    text = str(err.value)
    assert 'opcua.security_policies: "Basic256Sha256_Sign" signs but does not encrypt' in text, text
    assert 'use ["Basic256Sha256_SignAndEncrypt"]' in text, text


def test_config_check_says_both_refusals(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = HARDWARE.read_text(encoding="utf-8")
    lines = [line for line in text.splitlines() if not line.startswith("trusted_clients")]
    assert len(lines) == len(text.splitlines()) - 1
    before = 'security_policies = ["Basic256Sha256_SignAndEncrypt"]'
    assert text.count(before) == 1
    cfg = tmp_path / "cell.toml"
    cfg.write_text("\n".join(lines).replace(before, 'security_policies = ["Basic256Sha256_Sign"]') + "\n", encoding="utf-8")
    rc, out, err = run_cli(capsys, "config", "check", "--config", str(cfg))
    assert rc == 2 and "NOT OK" in err, out + err
    assert "opcua.trusted_clients" in err and '"Basic256Sha256_Sign" signs but does not encrypt' in err, err
