"""`cellctl config check | head -1`: once the reader of standard output has gone, cellctl ends quietly with the
status of a Unix tool ended by SIGPIPE (141), buffered output or not; a real pipe, a real process."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

SIM = Path(__file__).resolve().parents[2] / "config" / "sim.toml"


@pytest.mark.parametrize("unbuffered", [True, False])
def test_a_closed_stdout_ends_quietly(unbuffered: bool) -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("CELLCTL_", "PYTHONUNBUFFERED"))}
    if unbuffered:
        env["PYTHONUNBUFFERED"] = "1"
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader has gone before the first line (as `head -1` after it)
    try:
        done = subprocess.run([sys.executable, "-m", "cellctl", "config", "check", "--config", str(SIM)],
                              stdout=write_end, stderr=subprocess.PIPE, text=True, timeout=60, env=env)  # fmt: skip
    finally:
        os.close(write_end)
    assert done.stderr == "", done.stderr
    assert done.returncode == 128 + signal.SIGPIPE


def test_through_a_shell_pipe_the_first_line_comes_and_nothing_else() -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("CELLCTL_")} | {"PYTHONUNBUFFERED": "1"}
    cmd = f"'{sys.executable}' -m cellctl config check --config '{SIM}' | head -1"
    done = subprocess.run(["sh", "-c", cmd], capture_output=True, text=True, timeout=60, env=env)
    assert done.stdout == f"OK: {SIM}\n" and done.stderr == "", done.stderr
