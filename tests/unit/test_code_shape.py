"""The code's shape rules, checked rather than remembered: no hand-written source file over 500 lines, and nothing
the linter finds (ruff, with pyproject.toml's [tool.ruff]: unused imports and variables, undefined names)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
MAX_LINES = 500
GENERATED = {"egm_pb2.py"}  # protoc output


def test_no_source_file_is_over_500_lines() -> None:
    files = [*ROOT.glob("src/cellctl/**/*.py"), *ROOT.glob("src/cellctl/api/static/*.js"), *ROOT.glob("drivers/**/*.py")]
    assert len(files) > 100  # the globs found the tree
    long = {
        str(f.relative_to(ROOT)): n
        for f in files
        if f.name not in GENERATED and (n := len(f.read_text(encoding="utf-8").splitlines())) > MAX_LINES
    }
    assert not long, f"split these at their seams (a file past {MAX_LINES} lines is usually two): {long}"


def test_the_linter_finds_nothing() -> None:
    run = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "src", "drivers", "tests", "scripts", "examples"],
                         cwd=ROOT, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert run.returncode == 0, run.stdout + run.stderr
    assert "All checks passed" in run.stdout
