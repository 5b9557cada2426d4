"""`cellctl calibrate ...` following a job when the service stops: it ends, non-zero, saying what happened and what to do.

The end-to-end case runs `cellctl serve` and the CLI as processes, stops the service with SIGTERM mid-job, and holds
the CLI's words against the job's row read with sqlite3. The others drive ``follow`` with a stand-in service whose
event stream ends the ways a stopping service ends it.
"""

from __future__ import annotations

import io
import os
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from service_test_support import AUTH, TOKEN, sim_toml, start_serve, wait_up

from cellctl.client import ServiceError
from cellctl.commissioning.terminal import follow

pytestmark = pytest.mark.timeout(240)
JOB = {"id": 7, "procedure": "laser", "state": "running"}


class StoppingService:
    """A service whose event stream plays ``events`` (a callable may stand for a step), then ends."""

    url = "http://127.0.0.1:1"
    _token = None

    def __init__(self, events: list[Any], *, answers_after_end: bool = False) -> None:
        self.script = events
        self.up = True
        self.answers_after_end = answers_after_end
        self.asked = threading.Event()

    def job(self, job_id: int) -> dict[str, Any]:
        if not self.up and not self.answers_after_end:
            raise ServiceError(f"cannot reach the cell service at {self.url}: connection refused (is `cellctl serve` running?)")
        self.asked.set()
        return dict(JOB)

    def events(self) -> Iterator[tuple[str, dict[str, Any]]]:
        for step in self.script:
            if callable(step):
                step(self)
            else:
                yield step
        self.up = False

    def answer_prompt(self, *a: Any) -> dict[str, Any]:
        raise ServiceError("not up")

    def cancel_job(self, job_id: int) -> dict[str, Any]:
        raise ServiceError("not up")


def _synced(svc: StoppingService) -> None:
    assert svc.asked.wait(10)  # the follower read the job once (as it does on the first status event)


def _going(svc: StoppingService) -> None:
    _synced(svc)
    svc.up = False


def _follow(svc: StoppingService) -> tuple[int | None, str]:
    out = io.StringIO()
    rc: list[int] = []
    t = threading.Thread(target=lambda: rc.append(follow(svc, dict(JOB), out=out, stdin=None, events_client=svc)),  # type: ignore[arg-type]
                         daemon=True)  # fmt: skip
    t.start()
    t.join(15)
    return (rc[0] if rc else None), out.getvalue()


def test_a_stream_that_just_ends_ends_the_follow_saying_the_service_stopped_and_what_to_do() -> None:
    svc = StoppingService([("status", {}), _synced,
                           ("job", {"job_id": 7, "state": "running", "progress": {"done": 36, "total": 120, "message": "pose 36"}})])  # fmt: skip
    rc, out = _follow(svc)
    assert rc == 1, f"follow did not end (rc {rc}); it showed:\n{out}"
    assert "service stopped while job 7 (laser)" in out and "36/120" in out, out
    assert "start the service again" in out and "start the job again" in out and "/jobs/7" in out, out


def test_a_shutdown_event_ends_the_follow_though_the_service_still_answers() -> None:
    hold = threading.Event()
    svc = StoppingService([("status", {}), _synced, ("shutdown", {}), lambda s: hold.wait()], answers_after_end=True)
    rc, out = _follow(svc)
    assert rc == 1, f"follow did not end (rc {rc}); it showed:\n{out}"
    assert "the service is stopping" in out and "last seen running" in out and "start the service again" in out, out


def test_the_jobs_own_end_is_shown_when_the_service_is_gone_right_after_it() -> None:
    end = {"job_id": 7, "procedure": "laser", "state": "cancelled", "error": "the service is stopping",
           "dataset": "/cal/datasets/laser_plane-job7", "result": None, "progress": {"done": 36, "total": 120}}  # fmt: skip
    svc = StoppingService([("status", {}), _going, ("job", end), ("shutdown", {})])
    rc, out = _follow(svc)
    assert rc == 1, f"follow did not end as it should (rc {rc}); it showed:\n{out}"
    assert "laser: CANCELLED: the service is stopping" in out and "dataset: /cal/datasets/laser_plane-job7" in out, out
    assert "start the service again" in out, out


@pytest.mark.parametrize(("at", "port"), [("prompt", 18901), ("moving", 18902)])
def test_the_cli_ends_with_the_jobs_end_when_the_service_is_stopped_mid_job(tmp_path: Path, at: str, port: int) -> None:
    cfg = tmp_path / "cell.toml"
    cfg.write_text(sim_toml(port, oracle=False, auto_calibrate=False).replace('answers = "all"', 'answers = "actions"', 1))
    url = f"http://127.0.0.1:{port}"
    serve = start_serve(cfg, tmp_path)
    cli = None
    try:
        wait_up(url, serve, tmp_path)
        c = httpx.Client(base_url=url, timeout=10)
        assert c.post("/commands/clear", headers=AUTH).status_code == 200
        while c.get("/status").json()["state"] != "STOPPED":
            time.sleep(0.05)
        cli = subprocess.Popen([sys.executable, "-m", "cellctl.cli", "--config", str(cfg), "calibrate", "laser", "--poses", "120"],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                               env=dict(os.environ, CELLCTL_TOKEN=TOKEN), text=True)  # fmt: skip
        while not c.get("/jobs").json():
            time.sleep(0.05)
        jid = c.get("/jobs").json()[0]["id"]
        while not ((p := c.get(f"/jobs/{jid}").json()["prompt"]) and p["kind"] == "confirm_start"):
            time.sleep(0.05)
        if at == "moving":
            assert cli.stdin is not None
            cli.stdin.write("\n")  # the engineer confirms at the CLI
            cli.stdin.flush()
            while (c.get(f"/jobs/{jid}").json().get("progress") or {}).get("done", 0) < 5:
                time.sleep(0.02)
        serve.send_signal(signal.SIGTERM)  # systemctl stop, or Ctrl-C in the service's terminal
        assert serve.wait(60) == 0
        db = sqlite3.connect(tmp_path / "var" / "cellctl.db")
        state, error = db.execute("SELECT state, error FROM jobs WHERE id = ?", (jid,)).fetchone()
        db.close()
        assert (state, error) == ("cancelled", "the service is stopping")  # what really happened
        try:
            rc = cli.wait(30)
        except subprocess.TimeoutExpired:
            cli.kill()
            pytest.fail(f"the CLI still waits after the service stopped (job {jid} {state}: {error}):\n{cli.communicate()[0][-800:]}")
        out = cli.communicate()[0]
        assert rc == 1, out[-800:]
        assert f"laser: CANCELLED: {error}" in out, out[-800:]  # the job's own end reached the CLI
        assert f"stopped while job {jid}" in out and "start the service again" in out, out[-800:]
    finally:
        if cli is not None and cli.poll() is None:
            cli.kill()
        if serve.poll() is None:
            serve.send_signal(signal.SIGTERM)
            serve.wait(60)
