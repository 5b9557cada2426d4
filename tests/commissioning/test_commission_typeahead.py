"""`cellctl calibrate` at the keyboard (a terminal): only what is typed after a prompt is shown answers it.

An Enter pressed twice at the car-body prompt must not confirm the next prompt (that the robot's way to
its first pose is clear) before the engineer has read it. Real `cellctl serve` and `cellctl calibrate`
processes, the latter's input a pseudo-terminal; the service's own job record is the judge. (Piped input is
a script's answers, taken in order: tests/hardware pipes them.)
"""

from __future__ import annotations

import os
import pty
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
from service_test_support import serve_to_commission, wait_up

TOKEN = "sim-operator-token-change-me"  # config/sim.toml's operator token


def _wait_for(out: list[str], text: str, proc: subprocess.Popen[str], timeout_s: float = 60.0) -> None:
    t0 = time.monotonic()
    while not any(text in line for line in out):
        assert proc.poll() is None and time.monotonic() - t0 < timeout_s, "".join(out)
        time.sleep(0.05)


def test_an_enter_typed_ahead_does_not_confirm_the_next_prompt(tmp_path: Path) -> None:
    serve, url = serve_to_commission(tmp_path)
    env = {**os.environ, "CELLCTL_TOKEN": TOKEN}
    cli, keyboard = None, -1
    try:
        wait_up(url, serve, tmp_path)
        run = [sys.executable, "-m", "cellctl.cli", "--config", str(tmp_path / "cell.toml")]
        subprocess.run([*run, "command", "clear"], env=env, check=True, capture_output=True)
        keyboard, terminal = pty.openpty()
        cli = subprocess.Popen([*run, "calibrate", "laser", "--poses", "120"], stdin=terminal, stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True, env=env)  # fmt: skip
        os.close(terminal)
        out: list[str] = []
        threading.Thread(target=lambda: out.extend(cli.stdout or ()), daemon=True).start()
        _wait_for(out, "[car_body_in_place]", cli)
        os.write(keyboard, b"\n\n")  # Enter twice at the car-body prompt
        _wait_for(out, "[confirm_start]", cli)
        _wait_for(out, "typed before this prompt were dropped", cli)
        time.sleep(1.0)  # what a taken Enter would have needed to confirm it
        job = httpx.get(f"{url}/jobs", headers={"Authorization": f"Bearer {TOKEN}"}).json()
        (mine,) = [j for j in (job if isinstance(job, list) else job["jobs"]) if j["procedure"] == "laser"]
        current = httpx.get(f"{url}/jobs/{mine['id']}", headers={"Authorization": f"Bearer {TOKEN}"}).json()
        assert current["state"] == "running" and (current.get("prompt") or {}).get("kind") == "confirm_start", current
    finally:
        if cli is not None and cli.poll() is None:
            cli.send_signal(signal.SIGINT)
            try:
                cli.wait(15)
            except subprocess.TimeoutExpired:
                cli.kill()
        if keyboard >= 0:
            os.close(keyboard)
        serve.send_signal(signal.SIGINT)
        try:
            serve.wait(30)
        except subprocess.TimeoutExpired:
            serve.kill()
