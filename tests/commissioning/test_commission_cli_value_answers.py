"""`cellctl calibrate` at a prompt that asks for a value: only a finite number answers it, and a CLI that stops on an
error it does not handle cancels its job rather than leave it open with nobody at its prompts.

Real `cellctl serve` (the uncommissioned simulated cell, its simulated engineer answering nothing) and the CLI's own
code path with typed answers; the service's job record over REST is the judge.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import httpx
import pytest
from service_test_support import AUTH, TOKEN, stopped_cell_to_commission

from cellctl.client import CellClient, ServiceError
from cellctl.commissioning.terminal import follow

pytestmark = pytest.mark.timeout(180)


@pytest.fixture()
def cell(tmp_path: Path):  # type: ignore[no-untyped-def]
    with stopped_cell_to_commission(tmp_path) as url:
        yield url, tmp_path


def _job(url: str, job_id: int) -> dict[str, Any]:
    return dict(httpx.get(f"{url}/jobs/{job_id}", headers=AUTH).json())


def test_nan_and_infinity_are_asked_again_and_a_finite_size_answers(cell: tuple[str, Path]) -> None:
    url, workdir = cell
    # Enter: the car body is in place; then at "measured square size (mm)": nan, inf, -inf, 1e999 (inf as a float),
    # then 10.02; c cancels at the next prompt (the way to the first pose clear?), before anything moves.
    typed = "\nnan\ninf\n-inf\n1e999\n10.02\nc\n"
    p = subprocess.run([sys.executable, "-m", "cellctl.cli", "--config", str(workdir / "cell.toml"), "calibrate", "camera"],
                       input=typed, capture_output=True, text=True, timeout=120, env={**os.environ, "CELLCTL_TOKEN": TOKEN})  # fmt: skip
    out = p.stdout + p.stderr
    (job,) = httpx.get(f"{url}/jobs", headers=AUTH).json()
    job = _job(url, job["id"])
    assert "Traceback" not in out, out[-2000:]
    assert job["state"] == "cancelled" and job["prompt"] is None, job
    assert p.returncode == 1 and "camera: CANCELLED" in out, out[-2000:]
    for word in ("nan", "inf", "-inf", "1e999"):
        assert f"'{word}' is not an answer: press Enter to confirm, type a number or c to cancel" in out, out[-2000:]
    assert "answered by operator: value, 10.02" in out, out[-2000:]
    # the size the service took, as the job's (partial) dataset records it
    manifest = json.loads((Path(job["dataset"]) / "manifest.json").read_text())
    assert manifest["board"]["square_mm"] == 10.02, manifest["board"]


def test_a_second_job_is_refused_saying_how_to_cancel_and_an_unhandled_error_cancels_the_followed_job(
    cell: tuple[str, Path],
) -> None:
    url, _ = cell
    client = CellClient(url, TOKEN)
    job = client.start_job("camera", {})
    while (_job(url, job["id"]).get("prompt") or {}).get("kind") != "car_body_in_place":
        time.sleep(0.05)
    with pytest.raises(ServiceError) as refused:
        client.start_job("laser", {})
    assert f"job {job['id']} (camera) is running" in str(refused.value), refused.value
    assert f"POST /jobs/{job['id']}/cancel" in str(refused.value) and "dashboard" in str(refused.value), refused.value

    def broken(*args: Any, **kwargs: Any) -> dict[str, Any]:  # a fault of the CLI's side, past what it handles
        raise RuntimeError("a bug in this terminal")

    client.answer_prompt = broken  # type: ignore[method-assign]
    out = io.StringIO()
    with pytest.raises(RuntimeError, match="a bug in this terminal"):
        follow(client, job, out=out, stdin=io.StringIO("\n"))  # Enter at the car-body prompt
    ended = _job(url, job["id"])
    assert ended["state"] == "cancelled" and ended["prompt"] is None, ended
    text = out.getvalue()
    assert f"stopped following job {job['id']} on an error (RuntimeError: a bug in this terminal)" in text, text
    assert f"job {job['id']} cancelled" in text and "camera: CANCELLED" in text, text
    client.close()
