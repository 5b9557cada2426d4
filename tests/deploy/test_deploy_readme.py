"""The README's install steps create what deploy/cellctl.service assumes: its user, program, config, env file, folder."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _install_block() -> str:
    readme = (REPO / "README.md").read_text()
    start = readme.index("**Installing on a cell's PC**")
    return readme[start : readme.index("```\n", readme.index("```sh", start) + 5)]


def test_the_install_steps_make_everything_the_unit_names() -> None:
    unit = dict(
        line.split("=", 1) for line in (REPO / "deploy" / "cellctl.service").read_text().splitlines()
        if re.match(r"^[A-Za-z]+=", line)
    )  # fmt: skip
    steps = _install_block()
    exec_start = shlex.split(unit["ExecStart"])
    config = exec_start[exec_start.index("--config") + 1]
    assert "useradd --system" in steps and re.search(rf"\b{unit['User']}\b\s*$", steps.split("useradd", 1)[1].splitlines()[0])
    assert "--groups dialout" in steps and unit["SupplementaryGroups"] == "dialout"
    venv = exec_start[0].removesuffix("/bin/cellctl")
    assert f"python3 -m venv {venv}" in steps and f"{venv}/bin/pip install '.[camera]'" in steps
    assert f"config/hardware.example.toml {config}" in steps
    assert f"deploy/cellctl.env.example {unit['EnvironmentFile']}" in steps
    assert re.search(rf"install -d .*-o {unit['User']} .*{re.escape(unit['WorkingDirectory'])}\n", steps)
    assert "deploy/cellctl.service /etc/systemd/system/" in steps
    doc = unit["Documentation"].removeprefix("file://")
    assert f"cp README.md {Path(doc).parent}/" in steps
