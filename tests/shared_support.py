"""What every test folder may need: a free loopback port, a scratch folder that does not outlive the run, and
"skip here, but fail on CI" for optional kit."""

from __future__ import annotations

import asyncio
import atexit
import os
import random
import shutil
import socket
import tempfile
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

LOOPBACK = "127.0.0.1"


def on_ci() -> bool:
    """True under CI (CI=true), where every optional piece the tests use must be installed."""
    return os.environ.get("CI", "").lower() in ("1", "true", "yes")


def skip_or_fail(reason: str, fix: str) -> NoReturn:
    """Skip for want of an optional tool on a workstation; on CI that is a failure naming ``fix``."""
    if on_ci():
        pytest.fail(f"{reason} (CI must provide it: {fix})")
    pytest.skip(reason)


_scratch_root: list[str] = []


def scratch_dir(name: str) -> Path:
    """A new folder for what a cached helper writes outside any one test's ``tmp_path`` (a dataset, a calibration
    store); all of them go when this test process ends: the calibration tests' datasets alone are about 250 MB a run."""
    if not _scratch_root:
        _scratch_root.append(tempfile.mkdtemp(prefix="cellctl-tests-"))
        atexit.register(shutil.rmtree, _scratch_root[0], True)
    return Path(tempfile.mkdtemp(prefix=f"{name}-", dir=_scratch_root[0]))


_PORTS_PER_WORKER = 3000
_next_port: list[int] = []


def _first_port() -> int:
    """Where this process's ports start: below the kernel's ephemeral range (32768 up), one stripe per xdist worker."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    index = int(worker[2:]) if worker[2:].isdigit() else 0
    return 20000 + (index % 4) * _PORTS_PER_WORKER + random.randrange(_PORTS_PER_WORKER)


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """A loopback port nobody holds now (TCP, or UDP with SOCK_DGRAM), for a server the test starts next.

    Chosen below the ephemeral range, in turn within this worker's stripe: a port the kernel handed out as "any free
    one" (bind to 0) could be handed out again, to the sending socket of a fake, before the test's server binds it.
    """
    if not _next_port:
        _next_port.append(_first_port())
    base = 20000 + (_next_port[0] - 20000) // _PORTS_PER_WORKER * _PORTS_PER_WORKER
    for _ in range(_PORTS_PER_WORKER):
        port = _next_port[0]
        _next_port[0] = base + (port + 1 - base) % _PORTS_PER_WORKER
        with socket.socket(socket.AF_INET, kind) as s:
            try:
                s.bind((LOOPBACK, port))
            except OSError:
                continue
            return port
    raise RuntimeError(f"no free loopback port in {base}-{base + _PORTS_PER_WORKER - 1}")


def held_open(sock: socket.socket) -> bool:
    """Whether the server still holds ``sock``'s connection (nothing to read, no end of stream, no reset)."""
    try:
        return sock.recv(1, socket.MSG_DONTWAIT) != b""
    except BlockingIOError:
        return True
    except OSError:
        return False


def tlsimu_path() -> str:
    """TLSimu.cti, the simulated GenTL producer of the genicam wheel (1.3.0-1.5.0)."""
    fix = "pip install -e '.[camera]' (genicam>=1.3,<1.5.1)"
    try:
        import genicam
        import harvesters.core  # noqa: F401
    except ImportError as err:
        skip_or_fail(f"the optional extra 'camera' (harvesters, genicam) is not installed: {err}", fix)
    path = os.path.join(os.path.dirname(genicam.__file__), "TLSimu.cti")
    if not os.path.isfile(path):
        skip_or_fail(f"genicam {getattr(genicam, '__version__', '?')} has no TLSimu.cti (only 1.3.0-1.5.0 ship it)", fix)
    return path


def edge_crossing(profile: np.ndarray, centre: float, half: int = 7) -> float:
    """The 50 % crossing (cubic spline) between the plateaus either side of ``centre`` in a rendered profile."""
    k0 = int(np.floor(centre))
    pos = np.arange(k0 - half, k0 + half + 2)
    vals = profile[pos].astype(float)
    spline = CubicSpline(pos, vals - 0.5 * (vals[:3].mean() + vals[-3:].mean()))
    roots = [r for r in spline.roots(extrapolate=False) if pos[3] <= r <= pos[-4]]
    assert len(roots) == 1, f"expected one crossing near {centre:.2f}, got {roots}"
    return float(roots[0])


def run_cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    """``cellctl argv`` in this process: exit status (argparse's SystemExit too), stdout, stderr."""
    from cellctl.cli import main

    try:
        rc = main(list(argv))
    except SystemExit as stop:
        rc = int(stop.code or 0)
    out, err = capsys.readouterr()
    return rc, out, err


async def eventually(what: str, check: Callable[[], Awaitable[Any]], timeout_s: float = 20.0) -> Any:
    """Wait until ``check()`` gives something true, and return it (polled every 50 ms); fail naming ``what`` after
    ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if value := await check():
            return value
        await asyncio.sleep(0.05)
    raise AssertionError(f"not within {timeout_s} s: {what}")


def read_store(db_path: Any, sql: str, *args: object) -> list[tuple[Any, ...]]:
    """Rows of ``sql`` read from the cell's store file by a read-only sqlite3 connection of the test's own."""
    import sqlite3

    db = sqlite3.connect(f"file:{db_path}?mode=ro", uri=True)
    try:
        return db.execute(sql, args).fetchall()
    finally:
        db.close()


def door_window_first(tweak: Callable[[dict[str, Any]], None] | None = None) -> Any:
    """config/sim.toml as a CellConfig with the door-window recipe first (the benches' cycles take the first), after
    ``tweak`` edited its parsed TOML (e.g. turned the closed loop off)."""
    import tomllib
    from pathlib import Path

    from cellctl.config import parse_config

    data = tomllib.loads((Path(__file__).resolve().parents[1] / "config" / "sim.toml").read_text())
    recipes = data["process"]["recipes"]
    data["process"]["recipes"] = [r for r in recipes if r["name"] == "door-window"] + [r for r in recipes if r["name"] != "door-window"]
    if tweak is not None:
        tweak(data)
    return parse_config(data, "test: door window first")


def glass_moved_at_release(delta: Any) -> Any:
    """A RunHooks for the benches' runs: at each release the twin's glass lands moved by ``delta`` (4x4, about its
    corner frame G: T_B_G @ delta), its truth and scene with it."""
    from cellctl.bench.accuracy import RunHooks
    from cellctl.sim.glass import glass_scene

    class GlassMovedAtRelease(RunHooks):
        def attach(self, service: Any) -> None:
            cell = service.extras["twin"].cell
            release = cell.set_gripper

            def set_gripper(hold: bool) -> None:
                held = cell._glass_on_gripper
                release(hold)
                if not hold and held:
                    cell._installed_T_B_G = cell._installed_T_B_G @ delta
                    cell._installed_scene = glass_scene(cell.glass_config, cell._world, cell._installed_T_B_G)

            cell.set_gripper = set_gripper

    return GlassMovedAtRelease()
