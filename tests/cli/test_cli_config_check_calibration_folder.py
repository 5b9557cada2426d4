"""`calibration.directory`: `config check` notes the --workdir only for a relative folder, and a folder that lies
under a regular file is refused by `config check --secrets` and by `serve`, naming the setting and the fix."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from shared_support import free_port, run_cli

ROOT = Path(__file__).resolve().parents[2]
SIM, HARDWARE = ROOT / "config" / "sim.toml", ROOT / "config" / "hardware.example.toml"
NOTE = "(relative to the service's --workdir)"
FIX = "set calibration.directory to a folder the service can write"


def _calibration_line(out: str) -> str:
    return next(line for line in out.splitlines() if "calibration store" in line)


@pytest.mark.parametrize(("directory", "noted"), [("/var/lib/cellctl/calibration", False), ("var/calibration", True)])
def test_the_workdir_note_is_shown_for_a_relative_folder_only(
    directory: str, noted: bool, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = tmp_path / "cell.toml"
    cfg.write_text(SIM.read_text(encoding="utf-8").replace('directory = "var/calibration"', f'directory = "{directory}"', 1))
    rc, out, err = run_cli(capsys, "config", "check", "--config", str(cfg))
    assert rc == 0, err
    line = _calibration_line(out)
    assert directory in line and (NOTE in line) == noted, line


def test_the_hardware_examples_absolute_folder_has_no_workdir_note(capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, err = run_cli(capsys, "config", "check", "--config", str(HARDWARE))
    assert rc == 0, err
    assert _calibration_line(out).split() == ["calibration", "store", "/var/lib/cellctl/calibration"]


def _config_under_a_file(tmp_path: Path) -> tuple[Path, Path]:
    """The simulated cell on free loopback ports, its calibration folder under a regular file."""
    (tmp_path / "file.txt").write_text("x")
    folder = tmp_path / "file.txt" / "cal"
    text = SIM.read_text(encoding="utf-8").replace('directory = "var/calibration"', f'directory = "{folder}"', 1)
    for old, new in ((r"\nport = 8080\n", f"\nport = {free_port()}\n"), (r"\nport = 5020\n", f"\nport = {free_port()}\n"),
                     (r"\nport = 4840 ", f"\nport = {free_port()} ")):  # fmt: skip
        text, n = re.subn(old, new, text, count=1)
        assert n == 1, old
    cfg = tmp_path / "cell.toml"
    cfg.write_text(text, encoding="utf-8")
    return cfg, folder


def test_a_folder_under_a_file_is_refused_by_check(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg, folder = _config_under_a_file(tmp_path)
    with pytest.raises(NotADirectoryError):  # the truth: the folder cannot be made
        folder.mkdir(parents=True)
    rc, out, err = run_cli(capsys, "config", "check", "--config", str(cfg), "--secrets", "--workdir", str(tmp_path))
    assert rc == 2 and out == "", out
    assert f"calibration.directory {folder}: the folder cannot be created ({tmp_path / 'file.txt'} is a file" in err
    assert FIX in err


def test_a_folder_under_a_file_is_refused_by_serve_before_it_starts(tmp_path: Path) -> None:
    cfg, folder = _config_under_a_file(tmp_path)
    env = {k: v for k, v in os.environ.items() if not k.startswith("CELLCTL_")}
    try:
        done = subprocess.run([sys.executable, "-m", "cellctl", "serve", "--config", str(cfg), "--workdir", str(tmp_path)],
                              capture_output=True, text=True, timeout=30, env=env)  # fmt: skip
    except subprocess.TimeoutExpired:
        pytest.fail("serve started with its calibration folder under a file")
    assert done.returncode == 2, done.stderr  # a configuration problem
    assert done.stderr.strip().splitlines() == [f"error: calibration.directory {folder}: the folder cannot be created "
                                                f"({tmp_path / 'file.txt'} is a file, not a folder); {FIX} (e.g. "
                                                "\"var/calibration\" under --workdir, or /var/lib/cellctl/calibration)"]  # fmt: skip
    assert not (tmp_path / "var").exists()  # refused before the store was made
