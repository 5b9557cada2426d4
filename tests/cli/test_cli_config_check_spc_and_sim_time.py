"""`cellctl config check` refuses (exit 2, naming the field and the fix) what `cellctl serve` refuses, run as the real
commands in subprocesses (the OS's exit status and stderr are the peer):

- an install tolerance ([process.tolerance]) at or below the SPC drift limit ([process.spc] drift_limit_*): the loop's
  estimate could never reach the limit. `serve` used to die on it with a traceback (exit 1), `config check` said OK;
- process.align.mode = "on_the_fly" with the devices on their protocol fakes, which need sim.time_scale = 1.0.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
from service_test_support import ROOT, sim_toml

pytestmark = pytest.mark.timeout(300)


def _cellctl(cfg: Path, *argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "cellctl.cli", "--config", str(cfg), *argv], capture_output=True,
                          text=True, timeout=180, cwd=ROOT, stdin=subprocess.DEVNULL)  # fmt: skip


def _config(tmp_path: Path, *edits: tuple[str, str]) -> Path:
    """config/sim.toml (REST on any free port, PLC and OPC UA off) with each (pattern, line) replaced once."""
    text = sim_toml(0)
    for pattern, line in edits:
        text, n = re.subn(pattern, line, text, count=1, flags=re.MULTILINE)
        assert n == 1, pattern
    cfg = tmp_path / "cell.toml"
    cfg.write_text(text, encoding="utf-8")
    return cfg


TOLERANCES = {
    "position": (r"^position_mm = 0\.5 ", "position_mm = 0.2 ", "process.spc.drift_limit_mm: 0.25 is not below the "
                 "install tolerance process.tolerance.position_mm = 0.2", "raise process.tolerance.position_mm above 0.25"),
    "orientation": (r"^orientation_deg = 1\.0 ", "orientation_deg = 0.08 ", "process.spc.drift_limit_deg: 0.08 is not "
                    "below the install tolerance process.tolerance.orientation_deg = 0.08",
                    "lower process.spc.drift_limit_deg below 0.08"),
}  # fmt: skip


@pytest.mark.parametrize("axis", sorted(TOLERANCES))
def test_a_tolerance_at_or_below_the_drift_limit_is_refused_by_field_in_check_and_serve(tmp_path: Path, axis: str) -> None:
    pattern, line, field, fix = TOLERANCES[axis]
    cfg = _config(tmp_path, (pattern, line))
    check = _cellctl(cfg, "config", "check")
    assert check.returncode == 2 and check.stdout == "", (check.returncode, check.stdout, check.stderr)
    assert field in check.stderr and fix in check.stderr, check.stderr
    serve = _cellctl(cfg, "serve", "--workdir", str(tmp_path))
    assert serve.returncode == 2 and "Traceback" not in serve.stderr, serve.stderr[-600:]
    assert field in serve.stderr and fix in serve.stderr, serve.stderr[-600:]


def test_a_drift_limit_below_a_tight_tolerance_passes(tmp_path: Path) -> None:
    cfg = _config(tmp_path, (r"^position_mm = 0\.5 ", "position_mm = 0.2 "), (r"^drift_limit_mm = 0\.25 ", "drift_limit_mm = 0.15 "),
                  (r"^max_offset_mm = 0\.2 ", "max_offset_mm = 0.1 "))  # fmt: skip
    check = _cellctl(cfg, "config", "check")
    assert check.returncode == 0 and check.stdout.startswith("OK:"), check.stderr


def test_on_the_fly_through_the_fakes_needs_real_time_in_check_as_in_serve(tmp_path: Path) -> None:
    cfg = _config(tmp_path, (r'^mode = "stop_and_go"', 'mode = "on_the_fly"'))
    check = _cellctl(cfg, "config", "check")
    assert check.returncode == 2 and check.stdout == "", (check.returncode, check.stdout, check.stderr)
    assert "needs sim.time_scale = 1.0 (it is 0.001)" in check.stderr and 'process.align.mode = "on_the_fly"' in check.stderr
    serve = _cellctl(cfg, "serve", "--workdir", str(tmp_path))
    said = serve.stderr.strip().splitlines()[-1].removeprefix("error: ")
    assert serve.returncode == 2 and f"  - {said}" in check.stderr.splitlines(), (serve.stderr[-600:], check.stderr)


@pytest.mark.parametrize("fix", ["real time", "twin devices"])
def test_on_the_fly_passes_in_real_time_or_on_the_twins_own_devices(tmp_path: Path, fix: str) -> None:
    edits = [(r'^mode = "stop_and_go"', 'mode = "on_the_fly"')]
    own_fields = r"\n(\w+ = .*\n)+"  # the fake's settings below its kind
    edits += ([(r"^time_scale = .*$", "time_scale = 1.0")] if fix == "real time" else
              [(r'^kind = "sim_keyence_lkg"' + own_fields, 'kind = "sim"\n'), (r'^kind = "sim_abb"' + own_fields, 'kind = "sim"\n')])  # fmt: skip
    check = _cellctl(_config(tmp_path, *edits), "config", "check")
    assert check.returncode == 0 and "this cell: " in check.stdout, check.stderr
