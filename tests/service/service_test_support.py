"""A whole simulated cell service for tests: the real composition, a temporary workdir, port 0."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import time
import tomllib
from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from shared_support import free_port  # noqa: F401 - the service tests import it from here

from cellctl.config import CellConfig, parse_config
from cellctl.domain import AlarmCode
from cellctl.ports import Frame
from cellctl.service import build_service
from cellctl.service.compose import Service

ROOT = Path(__file__).resolve().parents[2]
TOKEN = "sim-operator-token-change-me"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def sim_config(**sections: dict[str, Any]) -> CellConfig:
    """config/sim.toml with some sections' fields replaced.

    Unless a test says otherwise the calibration is the twin's truth (the oracle): self-calibrating
    from simulated data takes half a minute, which the calibration tests cover on their own.
    """
    data = tomllib.loads((ROOT / "config" / "sim.toml").read_text())
    sections.setdefault("calibration", {"source": "oracle"})
    sections.setdefault("opcua", {"enabled": False})  # the OPC UA tests turn it on (its start costs about a second)
    sections["plc"] = {"port": 0} | sections.get("plc", {})  # never sim.toml's 5020: tests run side by side
    for name, fields in sections.items():
        node = data
        for part in name.split("."):
            node = node.setdefault(part, {})
        node.update(fields)
    return parse_config(data, "sim.toml (test)")


@contextlib.asynccontextmanager
async def running_service(workdir: Path, config: CellConfig | None = None) -> AsyncIterator[Service]:
    cfg = config or sim_config(plc={"port": 0, "scan_period_s": 0.005})
    service = await build_service(cfg, workdir=workdir)
    await service.start()
    try:
        yield service
    finally:
        await service.stop()


class BinnedCamera:
    """The cell's camera with 4 x 4 binning switched on while ``binned()`` says so (2048 x 2048 -> 512 x 512 px)."""

    def __init__(self, camera: Any, binned: Callable[[], bool]) -> None:
        self._camera, self._binned = camera, binned
        self.sizes: list[tuple[int, int]] = []  # (width, height) of every frame handed on

    async def grab(self, *, timeout_s: float) -> Frame:
        frame = await self._camera.grab(timeout_s=timeout_s)
        if self._binned():
            h, w = frame.image.shape
            image = frame.image.reshape(h // 4, 4, w // 4, 4).mean(axis=(1, 3)).astype(np.uint8)
            frame = dataclasses.replace(frame, image=image)
        self.sizes.append((frame.image.shape[1], frame.image.shape[0]))
        return frame

    def __getattr__(self, name: str) -> Any:
        return getattr(self._camera, name)


async def job_ended(client: httpx.AsyncClient, job_id: int, timeout_s: float = 300.0) -> dict[str, Any]:
    """A commissioning job's record once it has ended (neither running nor computing), waiting at most ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        job: dict[str, Any] = (await client.get(f"/jobs/{job_id}")).json()
        if job["state"] not in ("running", "computing"):
            return job
        await asyncio.sleep(0.05)
    raise AssertionError(f"job {job_id} did not end within {timeout_s} s")


@contextlib.asynccontextmanager
async def api_client(service: Service) -> AsyncIterator[httpx.AsyncClient]:
    from cellctl.api.app import create_app

    app = create_app(service.orchestrator, service.config.api, service.jobs)
    async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://cell") as client:
        yield client


async def _command(client: httpx.AsyncClient, cmd: str) -> str:
    """One PackML command over REST; the state once the acting state (Clearing, Resetting, ...) is over."""
    import asyncio

    r = await client.post(f"/commands/{cmd}", headers=AUTH)
    assert r.status_code == 200, r.text
    for _ in range(200):
        state = (await client.get("/status")).json()["state"]
        if not state.endswith("ING"):
            break
        await asyncio.sleep(0.01)
    return str(state)


async def to_execute(client: httpx.AsyncClient) -> None:
    """Clear, reset and start the cell over REST, waiting out the acting states."""
    for cmd in ("clear", "reset", "start"):
        state = await _command(client, cmd)
    assert state == "EXECUTE", state


async def back_to_execute(client: httpx.AsyncClient) -> None:
    """The operator's way back to Execute after a fault: the alarms acknowledged, then what the state asks for."""
    r = await client.post("/alarms/acknowledge-all", headers=AUTH)
    assert r.status_code == 200, r.text
    state = (await client.get("/status")).json()["state"]
    for cmd in {"ABORTED": ["clear", "reset", "start"], "STOPPED": ["reset", "start"], "HELD": ["unhold"]}.get(state, []):
        state = await _command(client, cmd)
    assert state == "EXECUTE", state


async def alarms_listed(client: httpx.AsyncClient) -> list[dict[str, Any]]:
    """The current alarms but a watchdog's late ping (DEVICE_SLOW, a warning without a reaction): on a loaded machine
    a device may answer a ping late in any test, which says nothing of what the test checks."""
    return [a for a in (await client.get("/alarms")).json()["current"] if a["code"] != AlarmCode.DEVICE_SLOW]


def slow_moves(service: Service, factor: float) -> None:
    """Make the robot's moves take ``factor`` times longer in real time (the ABB fake's time scale, which the
    twin's arm follows as each move begins); ``1 / factor`` undoes it."""
    robot = service.extras["fakes"]["robot"].robot
    robot.time_scale *= factor


def sim_toml(port: int, *, oracle: bool = True, auto_calibrate: bool = True, time_scale: float | None = None) -> str:
    """config/sim.toml for a `cellctl serve` subprocess: REST on ``port``, the PLC off, the calibration as asked."""
    import re

    text = (ROOT / "config" / "sim.toml").read_text()
    if oracle:
        text = re.sub(r'(?m)^source = "set"$', 'source = "oracle"', text, count=1)  # no minute of self-commissioning
    if not auto_calibrate:
        text = re.sub(r"(?m)^auto_calibrate_in_sim = true$", "auto_calibrate_in_sim = false", text, count=1)
    if time_scale is not None:
        text = re.sub(r"(?m)^time_scale = .*$", f"time_scale = {time_scale}", text, count=1)
    text = re.sub(r"(?m)^port = 8080$", f"port = {port}", text, count=1)
    text = text.replace("[opcua]                                # OPC UA server for the plant (OPC 30050 PackML; docs/opcua_nodeset.md)\nenabled = true",
                        "[opcua]\nenabled = false")
    return text.replace("[plc]                                  # Modbus TCP server for the line PLC\nenabled = true", "[plc]\nenabled = false")


def serve_to_commission(workdir: Path) -> tuple[Any, str]:
    """`cellctl serve` of the uncommissioned simulated cell whose simulated engineer answers no prompt: (process, URL);
    its config is ``workdir/cell.toml``."""
    port = free_port()
    cfg = workdir / "cell.toml"
    cfg.write_text(sim_toml(port, oracle=False, auto_calibrate=False).replace('answers = "all"', 'answers = "none"', 1))
    return start_serve(cfg, workdir), f"http://127.0.0.1:{port}"


@contextlib.contextmanager
def stopped_cell_to_commission(workdir: Path) -> Iterator[str]:
    """:func:`serve_to_commission`, up and cleared to Stopped: its URL. At the end a job the code under test left
    running is cancelled before the service is stopped (SIGINT)."""
    import signal
    import subprocess

    serve, url = serve_to_commission(workdir)
    try:
        wait_up(url, serve, workdir)
        with httpx.Client() as http:
            assert http.post(f"{url}/commands/clear", headers=AUTH).status_code == 200
            while http.get(f"{url}/status").json()["state"] != "STOPPED":
                time.sleep(0.05)
        yield url
    finally:
        for job in httpx.get(f"{url}/jobs", headers=AUTH).json() if serve.poll() is None else []:
            if job["state"] == "running":
                httpx.post(f"{url}/jobs/{job['id']}/cancel", headers=AUTH, timeout=30)
        serve.send_signal(signal.SIGINT)
        try:
            serve.wait(30)
        except subprocess.TimeoutExpired:
            serve.kill()


def start_serve(config: Path, workdir: Path) -> Any:
    """`cellctl serve` in a subprocess; its output goes to ``workdir/service.log``, and its temporary files (the LK-G
    fake's link, left behind by a killed service) to ``workdir``."""
    import os
    import subprocess
    import sys

    log = open(workdir / "service.log", "ab")  # noqa: SIM115 - the child writes it; closed with the child
    proc = subprocess.Popen([sys.executable, "-m", "cellctl.cli", "--config", str(config), "serve", "--workdir", str(workdir)],
                            stdout=log, stderr=log, env={**os.environ, "TMPDIR": str(workdir)})  # fmt: skip
    log.close()
    return proc


def wait_up(url: str, proc: Any, workdir: Path, deadline_s: float = 60.0, *, verify: Any = True) -> None:
    """Until GET /status answers (the process must stay alive meanwhile); ``verify`` as httpx takes it (an
    ``ssl.SSLContext`` trusting the plant's CA for an https ``url``)."""
    import time

    end = time.monotonic() + deadline_s
    with httpx.Client(verify=verify, timeout=2) as http:  # one client: a new one per try loads the CA bundle each time
        while True:
            try:
                if http.get(f"{url}/status").status_code == 200:
                    return
            except httpx.HTTPError:
                pass
            assert proc.poll() is None and time.monotonic() < end, (workdir / "service.log").read_text()
            time.sleep(0.1)


def truth_values(cal: Any, recipe: str) -> dict[str, dict[str, Any]]:
    """The oracle's calibration of ``recipe`` (the twin's truth) as the set's part values."""
    lens, t, m, taught = cal.lens, cal.template, cal.nine_point, cal.taught
    angle = lambda a: None if not np.isfinite(a) else float(a)  # noqa: E731
    return {
        "camera": {"K": lens.camera_matrix.tolist(), "dist": [lens.k1, lens.k2, lens.p1, lens.p2, lens.k3],
                   "image_size": [lens.width_px, lens.height_px]},
        "hand_eye": {"T_H_C": np.asarray(cal.T_H_C).tolist()},
        "laser": {"r": np.asarray(cal.laser_r).tolist(), "l": np.asarray(cal.laser_l).tolist()},
        "teaching": {"recipe": recipe, "T0": taught.T0.tolist(), "C_Pos_0": taught.C_Pos_0.tolist(),
                     "g_Pos_0": taught.g_Pos_0.tolist(), "u_d": t.u_px, "v_d": t.v_px, "theta_d": t.theta_rad,
                     "top_angle_d": angle(t.top_angle_rad), "right_angle_d": angle(t.right_angle_rad)},
        "pixel_map": {"affine": m.matrix.tolist(), "scale_mm_per_px": float(np.sqrt(abs(np.linalg.det(m.matrix[:, :2]))))},
    }  # fmt: skip


@contextlib.asynccontextmanager
async def served(service: Service) -> AsyncIterator[str]:
    """The service's REST API on a loopback port, as `cellctl serve` gives it (for a CLI in a subprocess)."""
    from cellctl.api.app import create_app
    from cellctl.service.http import make_server

    port = free_port()
    server = make_server(create_app(service.orchestrator, service.config.api, service.jobs), "127.0.0.1", port, lambda: None)
    task = asyncio.create_task(server.serve())
    try:
        while not server.started:
            assert not task.done(), "the HTTP server did not start"
            await asyncio.sleep(0.02)
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        await task
