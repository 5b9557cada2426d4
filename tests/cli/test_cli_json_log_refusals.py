"""With `--log-format json` every line `cellctl serve` writes to stderr is one JSON object, its refusal too."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_a_refused_configuration_is_one_json_record_naming_the_field(tmp_path: Path) -> None:
    cfg = tmp_path / "cell.toml"
    cfg.write_text((REPO / "config" / "sim.toml").read_text().replace("port = 8080\n", "port = 70000\n", 1))
    r = subprocess.run([sys.executable, "-m", "cellctl", "--log-format", "json", "serve", "--config", str(cfg), "--workdir", str(tmp_path)],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 2, r.stderr
    records = [json.loads(line) for line in r.stderr.splitlines() if line.strip()]  # fails on a line that is not JSON
    assert len(records) == 1 and records[0]["level"] == "ERROR", records
    assert records[0]["message"].startswith("configuration refused:") and "api.port" in records[0]["message"], records
    # text logs keep the plain message a person reads
    r = subprocess.run([sys.executable, "-m", "cellctl", "serve", "--config", str(cfg), "--workdir", str(tmp_path)],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 2 and r.stderr.startswith("configuration refused:\n"), r.stderr
