"""`cellctl calibrate <part> --list-poses` and `cellctl teach --list-poses` are a dry run: they list the plan, nothing moves.

Real `cellctl serve` (the uncommissioned simulated cell, in Stopped, where a job could start) and the CLI in a subprocess
without `--dry-run`; the judge is the service's job list over REST (no job started) and the CLI's output.
`--list-poses` or `--dry-run` with `--dataset` (an offline computation that stores its result) is refused.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from service_test_support import AUTH, TOKEN, stopped_cell_to_commission

pytestmark = pytest.mark.timeout(180)


@pytest.fixture()
def cell(tmp_path: Path) -> Iterator[tuple[str, Path]]:
    with stopped_cell_to_commission(tmp_path) as url:
        yield url, tmp_path


def _cli(workdir: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "cellctl.cli", "--config", str(workdir / "cell.toml"), *args],
                          stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "CELLCTL_TOKEN": TOKEN})  # fmt: skip


def test_list_poses_without_dry_run_lists_the_plan_and_starts_no_job(cell: tuple[str, Path]) -> None:
    url, workdir = cell
    p = _cli(workdir, "calibrate", "camera", "--list-poses", "--views", "8")
    assert p.returncode == 0, p.stdout + p.stderr
    assert httpx.get(f"{url}/jobs", headers=AUTH).json() == []
    assert "plan for camera: 8 poses" in p.stdout and "nothing moved (dry run)" in p.stdout, p.stdout
    assert p.stdout.count(" mm  ") == 8, p.stdout  # one line per pose: label, position (mm), angles (deg)
    p = _cli(workdir, "teach", "--list-poses")  # teaching needs the camera first: the plan says so, and nothing starts
    assert "camera must be calibrated first" in p.stdout + p.stderr, p.stdout + p.stderr
    assert httpx.get(f"{url}/jobs", headers=AUTH).json() == []


def test_list_poses_or_dry_run_with_a_dataset_is_refused(tmp_path: Path) -> None:
    for flag in ("--list-poses", "--dry-run"):
        p = subprocess.run([sys.executable, "-m", "cellctl.cli", "calibrate", "camera", flag, "--dataset", str(tmp_path),
                            "--workdir", str(tmp_path)], capture_output=True, text=True, timeout=60)  # fmt: skip
        assert p.returncode == 2 and f"{flag} plans a job on the cell; --dataset computes offline" in p.stderr, p.stderr
        assert list(tmp_path.iterdir()) == []
