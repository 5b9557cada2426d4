"""From an empty calibration store, the simulated cell is commissioned through the running service with the CLI alone.

`cellctl serve` runs the simulated cell (the LK-G and ABB drivers over their protocol fakes, the
twin behind them) with self-commissioning off; `cellctl calibrate camera|hand-eye|laser`,
`cellctl teach` and `cellctl calibrate nine-point` then run as jobs of that service, the
simulated operator answering their prompts. The calibration set they store is scored against
the twin's truth, and the cell then installs windows with it.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from datetime import datetime, timezone
from pathlib import Path

import httpx
import pytest
from service_test_support import TOKEN, free_port, sim_toml, start_serve, wait_up

from cellctl.calibration.calibration_set import CalibrationStore
from cellctl.calibration.readiness import check_ready

STEPS = (("calibrate", "camera"), ("calibrate", "hand-eye"), ("calibrate", "laser"), ("teach",), ("calibrate", "nine-point"))


@pytest.fixture()
def served_cell(tmp_path: Path):  # type: ignore[no-untyped-def]
    port = free_port()
    cfg = tmp_path / "cell.toml"
    cfg.write_text(sim_toml(port, oracle=False, auto_calibrate=False))
    proc = start_serve(cfg, tmp_path)
    try:
        wait_up(f"http://127.0.0.1:{port}", proc, tmp_path)
        yield cfg, f"http://127.0.0.1:{port}", tmp_path
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()


def _cli(cfg: Path, *args: str, timeout_s: float = 300.0) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "CELLCTL_TOKEN": TOKEN}
    return subprocess.run(
        [sys.executable, "-m", "cellctl.cli", "--config", str(cfg), *args],
        stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=timeout_s, env=env,
    )  # fmt: skip


def test_an_empty_cell_commissioned_with_the_cli_alone_meets_the_bars_and_installs(served_cell) -> None:  # type: ignore[no-untyped-def]
    cfg, url, workdir = served_cell
    run = _cli(cfg, "calibrate", "laser")
    assert run.returncode == 1 and "ABORTED" in run.stderr and "Clear" in run.stderr  # jobs need Stopped or Idle
    assert _cli(cfg, "command", "clear").returncode == 0
    for step in STEPS:
        run = _cli(cfg, *step)
        assert run.returncode == 0, f"{step}: {run.stdout}\n{run.stderr}"
        assert "stored as version" in run.stdout and "started on the cell" in run.stdout
    assert "ready for production" in run.stdout
    store = CalibrationStore(workdir / "var" / "calibration")
    cal = store.current()
    assert cal is not None and cal.version == len(STEPS)
    assert check_ready(cal, datetime.now(timezone.utc)) == []
    # The bars of `cellctl bench calibration`, against the twin's truth written beside each dataset.
    cam = cal.part("camera").quality["twin_truth"]
    assert abs(cam["fx_error_pct"]) < 0.2 and abs(cam["fy_error_pct"]) < 0.2
    assert abs(cam["cx_error_px"]) < 2.0 and abs(cam["cy_error_px"]) < 2.0
    he = cal.part("hand_eye").quality
    he_truth = he["twin_truth"][he["chosen"]]
    assert he_truth["translation_error_mm"] < 0.5 and he_truth["rotation_error_deg"] < 0.05
    laser = cal.part("laser").quality["twin_truth"]
    assert laser["r_error_mm"] < 0.3 and laser["l_error_deg"] < 0.02
    # Every part names the dataset it came from, and which cell and devices recorded it.
    for name in ("camera", "hand_eye", "laser", "teaching", "pixel_map"):
        ref = cal.part(name).dataset
        assert ref is not None and ref.path.startswith("datasets/") and (store.root / ref.path).is_dir()  # relative: the store can move
    # The jobs are on record, each started by the token's actor.
    jobs = httpx.get(f"{url}/jobs").json()
    assert [j["state"] for j in jobs] == ["done"] * len(STEPS) and {j["actor"] for j in jobs} == {"operator"}
    # Production with the commissioned set: each glass within a fraction of the tolerance.
    run = _cli(cfg, "cycle", "--start", "--count", "4")
    assert run.returncode == 0, run.stdout + run.stderr
    errors = re.findall(r"true install error: dx=(\S+) dy=(\S+) dz=(\S+) drx=(\S+) dry=(\S+) drz=(\S+)", run.stdout)
    assert len(errors) == 4
    for dx, dy, dz, rx, ry, rz in errors:
        assert max(abs(float(v)) for v in (dx, dy, dz)) < 0.35
        assert max(abs(float(v)) for v in (rx, ry, rz)) < 0.1
    # Each cycle records which calibration it used by reference (the set's version, the parts' ids), not a copy.
    record = httpx.get(f"{url}/cycles/1").json()
    used = next(step["figures"]["calibration"] for step in record["steps"] if step["step"] == "calibrate")
    assert used["version"] == cal.version and used["parts"]["laser"] == cal.part("laser").id
    assert "quality" not in str(used)
