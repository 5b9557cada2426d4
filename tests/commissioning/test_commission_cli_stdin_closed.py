"""`cellctl calibrate` whose input is gone (run from a script, a dropped SSH session): it says where the open prompt
can be answered and keeps following the job.

Real `cellctl serve` and `cellctl calibrate` processes, the latter's stdin a pipe closed at the start; the simulated
operator answers nothing. The prompt is then answered over REST at the address the CLI printed.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
from service_test_support import serve_to_commission, wait_up

TOKEN = "sim-operator-token-change-me"  # config/sim.toml's operator token
HEADERS = {"Authorization": f"Bearer {TOKEN}"}


def _wait_for(out: list[str], pattern: str, proc: subprocess.Popen[str], timeout_s: float = 60.0) -> re.Match[str]:
    t0 = time.monotonic()
    while (found := re.search(pattern, "".join(out))) is None:
        assert proc.poll() is None and time.monotonic() - t0 < timeout_s, "".join(out)
        time.sleep(0.05)
    return found


def test_a_closed_stdin_says_where_to_answer_and_keeps_following(tmp_path: Path) -> None:
    serve, url = serve_to_commission(tmp_path)
    env = {**os.environ, "CELLCTL_TOKEN": TOKEN}
    cli = None
    try:
        wait_up(url, serve, tmp_path)
        run = [sys.executable, "-m", "cellctl.cli", "--config", str(tmp_path / "cell.toml")]
        subprocess.run([*run, "command", "clear"], env=env, check=True, capture_output=True)
        cli = subprocess.Popen([*run, "calibrate", "laser", "--poses", "120"], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True, env=env)  # fmt: skip
        assert cli.stdin is not None
        cli.stdin.close()  # the input ends before the first prompt
        out: list[str] = []
        threading.Thread(target=lambda: out.extend(cli.stdout or ()), daemon=True).start()
        where = _wait_for(out, r"stays open.*POST (http://\S+/jobs/(\d+)/prompts/(\d+))", cli)
        assert "dashboard" in where.group(0), where.group(0)
        # The prompt is still open at the address printed, and the CLI still follows the job.
        job = httpx.get(f"{url}/jobs/{where.group(2)}", headers=HEADERS).json()
        assert job["state"] == "running" and job["prompt"]["id"] == int(where.group(3)), job
        assert httpx.post(where.group(1), json={"action": "confirm"}, headers=HEADERS).status_code == 200
        _wait_for(out, r"answered by [^\n]*: confirm", cli)
        assert httpx.post(f"{url}/jobs/{where.group(2)}/cancel", headers=HEADERS).status_code == 200
        assert cli.wait(30) == 1 and "CANCELLED" in "".join(out), "".join(out)
    finally:
        if cli is not None and cli.poll() is None:
            cli.kill()
        serve.send_signal(signal.SIGINT)
        try:
            serve.wait(30)
        except subprocess.TimeoutExpired:
            serve.kill()
