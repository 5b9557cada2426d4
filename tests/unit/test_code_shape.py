"""The code's shape rules, checked rather than remembered: no hand-written source file over 500 lines."""

from __future__ import annotations

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
