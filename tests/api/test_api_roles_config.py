"""REST roles in the configuration: ``role`` of [[api.tokens]] is viewer, operator or engineer (a bad one is
refused naming the field and the three), a token without one keeps all rights, and the shipped configs name each."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest
from service_test_support import ROOT, sim_config

from cellctl.cli import main
from cellctl.config import ConfigError, parse_config

SIM, HARDWARE = ROOT / "config" / "sim.toml", ROOT / "config" / "hardware.example.toml"
ALL_ENGINEERS = "every API token is an engineer"


def test_a_bad_role_is_refused_naming_the_field_and_the_roles(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = tomllib.loads(SIM.read_text())
    data["api"]["tokens"].append({"name": "line", "token": "line-Mb4nVc8sHd1j", "role": "admin"})
    with pytest.raises(ConfigError) as info:
        parse_config(data, "cell.toml")
    text = str(info.value)
    assert "api.tokens.1.role: token 'line': 'admin' is not a role; give 'viewer', 'operator' or 'engineer'" in text, text
    bad = tmp_path / "cell.toml"
    bad.write_text(SIM.read_text() + '\n[[api.tokens]]\nname = "line"\ntoken = "line-Mb4nVc8sHd1j"\nrole = "Operator"\n')
    assert main(["config", "check", "--config", str(bad)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and "api.tokens.1.role" in err and "'Operator' is not a role" in err, err


def test_a_token_without_a_role_keeps_all_rights() -> None:
    config = sim_config(api={"tokens": [{"name": "old", "token": "old-config-Tq7wLp2x"}]})
    assert config.api.roles() == {"old": "engineer"}


def test_the_shipped_configs_name_each_tokens_role() -> None:
    for path, roles in ((SIM, ["engineer"]), (HARDWARE, ["operator", "engineer"])):
        tokens = tomllib.loads(path.read_text())["api"]["tokens"]
        assert [t.get("role") for t in tokens] == roles, path


def test_config_check_says_when_every_token_is_an_engineer(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["config", "check", "--config", str(SIM)]) == 0
    out = capsys.readouterr().out
    assert "operator: engineer" in out and ALL_ENGINEERS in out, out
    assert main(["config", "check", "--config", str(HARDWARE)]) == 0
    out = capsys.readouterr().out
    assert "operator: operator, line-integrator: engineer" in out and ALL_ENGINEERS not in out, out


def test_the_roles_doc_is_generated_from_the_route_table() -> None:
    from cellctl.api import roles_doc

    doc = ROOT / "docs" / "api_roles.md"
    assert doc.read_text(encoding="utf-8") == roles_doc.render_markdown(), (
        "docs/api_roles.md is stale: python -m cellctl.api.roles_doc -o docs/api_roles.md")
    assert "| `POST /spc/reset` | `engineer` |" in doc.read_text() and "| `POST /cycle` | `operator` |" in doc.read_text()
