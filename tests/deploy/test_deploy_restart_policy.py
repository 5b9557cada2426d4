"""The unit does not restart a configuration `serve` refuses: the refusal's exit status (found by running `serve` on a
refused configuration, the truth) is the one the unit names in RestartPreventExitStatus, and other failed starts are
bounded by a start limit instead of repeating for ever."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
UNIT = REPO / "deploy" / "cellctl.service"


def _settings() -> dict[str, str]:
    out: dict[str, str] = {}
    for line in UNIT.read_text().splitlines():
        if "=" in line and not line.lstrip().startswith(("#", ";", "[")):
            key, _, value = line.partition("=")
            out[key.strip()] = value.strip()
    return out


def test_a_refused_configuration_is_not_restarted(tmp_path: Path) -> None:
    bad = tmp_path / "cell.toml"
    bad.write_text((REPO / "config" / "sim.toml").read_text(encoding="utf-8").replace("[process]\n", "[process]\nspeed = 1\n", 1))
    env = {k: v for k, v in os.environ.items() if not k.startswith("CELLCTL_")}
    done = subprocess.run([sys.executable, "-m", "cellctl", "--config", str(bad), "serve", "--workdir", str(tmp_path)],
                          capture_output=True, text=True, timeout=60, env=env, cwd=tmp_path)  # fmt: skip
    assert "process.speed" in done.stderr, done.stderr
    s = _settings()
    assert s["Restart"] == "on-failure"
    assert str(done.returncode) in s["RestartPreventExitStatus"].split(), (done.returncode, s.get("RestartPreventExitStatus"))
    # Any other failed start: at most StartLimitBurst tries within StartLimitIntervalSec, RestartSec apart.
    burst, interval, pause = int(s["StartLimitBurst"]), float(s["StartLimitIntervalSec"]), float(s["RestartSec"])
    assert burst * pause < interval, "the start limit must trip at the unit's own restart rate"
