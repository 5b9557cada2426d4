"""`cellctl config check` on copies of the shipped configuration files: the copy, the check, the refusal."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from shared_support import run_cli

from cellctl.config import load_config
from cellctl.config.loader import ConfigError

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = {"sim": ROOT / "config" / "sim.toml", "hardware": ROOT / "config" / "hardware.example.toml"}


def shipped_copy(tmp_path: Path, which: str, edits: tuple[tuple[str, str], ...] = (), extra: str = "") -> Path:
    """A copy of the shipped file with every host on 127.0.0.1, each (old, new) replaced once, ``extra`` appended."""
    text = SHIPPED[which].read_text(encoding="utf-8")
    text = re.sub(r'(?m)^host = "(0\.0\.0\.0|192\.168\.125\.1)"', 'host = "127.0.0.1"', text)
    for old, new in edits:
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    path = tmp_path / f"{which}.toml"
    path.write_text(text + extra, encoding="utf-8")
    return path


def check(capsys: pytest.CaptureFixture[str], cfg: Path) -> tuple[int, str]:
    """`config check --config cfg`: its exit status and stderr (never a traceback)."""
    rc, _out, err = run_cli(capsys, "config", "check", "--config", str(cfg))
    assert "Traceback" not in err, err
    return rc, err


def refused(capsys: pytest.CaptureFixture[str], cfg: Path) -> str:
    """`config check` exits 2 and `load_config` raises the same message (what `serve` refuses to start with)."""
    rc, err = check(capsys, cfg)
    with pytest.raises(ConfigError) as load:
        load_config(cfg)
    assert rc == 2 and str(load.value) in err, err
    return str(load.value)
