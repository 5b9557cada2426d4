"""A calibration folder that exists but that the service's user may not read and write is refused at start, naming
`calibration.directory` and the fix (it used to pass, and a calibration failed after its whole robot procedure).

The tests run cellctl with every capability dropped (`setpriv`), so that root is an ordinary user for the kernel's
permission check, the independent judge of what the service may do; the folder belongs to `nobody`."""

from __future__ import annotations

import os
import pwd
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from service_test_support import sim_toml
from shared_support import free_port

NOCAPS = ["setpriv", "--bounding-set=-all", "--inh-caps=-all"]
pytestmark = pytest.mark.skipif(os.geteuid() != 0 or shutil.which("setpriv") is None, reason="needs root and setpriv")


def _cell(tmp_path: Path, mode: int) -> tuple[Path, Path]:
    os.chmod(tmp_path, 0o755)
    folder = tmp_path / "var" / "calibration"
    folder.mkdir(parents=True)
    nobody = pwd.getpwnam("nobody")
    os.chown(folder, nobody.pw_uid, nobody.pw_gid)
    os.chmod(folder, mode)
    cfg = tmp_path / "cell.toml"
    cfg.write_text(sim_toml(free_port(), oracle=False), encoding="utf-8")  # the sim's set-sourced calibration
    return cfg, folder


def _cellctl(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("CELLCTL_")}
    return subprocess.run([*NOCAPS, sys.executable, "-m", "cellctl", *args], cwd=tmp_path, capture_output=True,
                          text=True, timeout=60, env=env)  # fmt: skip


@pytest.mark.parametrize("mode", [0o700, 0o555], ids=["unreadable", "read-only"])
def test_config_check_and_serve_refuse_a_folder_the_service_may_not_use(tmp_path: Path, mode: int) -> None:
    cfg, folder = _cell(tmp_path, mode)
    probe = subprocess.run([*NOCAPS, "sh", "-c", f"touch {folder}/probe"], capture_output=True)
    assert probe.returncode != 0  # the truth: without capabilities, this user may not write there
    why = f"calibration.directory {folder}: the service's user may not read and write in it; give it the right to"
    check = _cellctl(tmp_path, "config", "check", "--config", str(cfg), "--secrets", "--workdir", str(tmp_path))
    assert check.returncode == 2 and why in check.stderr, check.stdout + check.stderr
    serve = _cellctl(tmp_path, "serve", "--config", str(cfg), "--workdir", str(tmp_path))
    assert serve.returncode == 2 and serve.stderr.strip().splitlines()[-1].startswith(f"error: {why}"), serve.stderr
    assert not (tmp_path / "var" / "cellctl.db").exists()  # refused before the store was made
