"""Every docs/*.md the code, the README and the docs name exists (the OPC UA server's node descriptions, read by
the plant's clients, named a docs/alarms.md that never was)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOC_PATH = re.compile(r"\bdocs/[A-Za-z0-9_.-]+\.md\b")


def _sources() -> list[Path]:
    return [*ROOT.joinpath("src").rglob("*.py"), *ROOT.joinpath("drivers").rglob("*.py"), ROOT / "README.md",
            *ROOT.joinpath("docs").glob("*.md"), *ROOT.joinpath("config").glob("*.toml")]  # fmt: skip


def test_every_named_doc_exists() -> None:
    named = {(p.relative_to(ROOT).as_posix(), m) for p in _sources() for m in DOC_PATH.findall(p.read_text(encoding="utf-8"))}
    assert len(named) > 20  # the scan reads what it should
    missing = sorted((src, doc) for src, doc in named if not (ROOT / doc).is_file())
    assert not missing, missing
