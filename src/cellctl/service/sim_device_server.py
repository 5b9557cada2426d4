"""The simulated cell's devices in a process of their own: the LK-G and ABB protocol fakes, their physics from the twin.

``python -m cellctl.service.sim_device_server --config config/sim.toml --seed S`` holds one twin
(:class:`cellctl.sim.cell.SimCell` from the config's ``[sim]``, the car body at its nominal
placement), the LK-G fake controller on a pseudo-terminal and the ABB fake controller (RAPID line
server on a free loopback TCP port, no EGM), wired to the twin exactly as the simulated cell's
root wires them (:mod:`cellctl.service.sim_fakes`). A service in ``mode = "hardware"`` with
the real drivers pointed at them runs on the twin's physics without importing the twin.

When both serve, it prints ONE JSON line on stdout::

    {"lkg_port": "/dev/pts/N", "lkg_link": "/tmp/fake-lkg-.../ttyLKG0", "dialect": "LK-G5001",
     "display_unit": "0.001mm", "reference_distance_mm": 350.0, "displacement_positive": "away_from_head",
     "rapid_port": N, "control_port": N, "time_scale": 0.001,
     "truth": {"laser_r": [...], "laser_l": [...], "T_H_C": [[...]], "T_B_T": [[...]], "seed": S}}

``lkg_port``, ``dialect``, ``display_unit``, ``reference_distance_mm`` and ``displacement_positive``
are what ``[devices.laser]`` (kind ``keyence_lkg``) needs for the driver to read true distances;
``rapid_port`` is ``[devices.robot]``'s (host 127.0.0.1, ``egm_port`` omitted). ``truth`` is the
twin's true laser and camera mountings, to score a calibration against.

``control_port`` (loopback) is for tests, since the RAPID server takes one client at a time: a
connection sends one line and gets one JSON line back, the fake robot's state (``moving``,
``motors_on``, the flange pose it reports, ``time_scale``), then is closed. The line ``state``
only reads; ``time_scale X`` first sets the real seconds per simulated second of the moves that
begin from then on (e.g. slow moves down to stop one mid-way).

It then serves until SIGTERM or SIGINT, closes the fakes and exits 0. A configuration it
cannot use exits 2 with the reason on stderr.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import signal
import sys
from pathlib import Path
from typing import Any

from abb_robot.fake.controller import FakeController
from cellctl.config import ConfigError, load_config
from cellctl.config.devices import SimKeyenceLkgDevice
from cellctl.service.sim_fakes import LKG_DISPLACEMENT_POSITIVE, abb_fake, lkg_fake, lkg_reference_mm
from cellctl.sim.cell import SimCell
from cellctl.sim.world import nominal_world

log = logging.getLogger("cellctl.sim_device_server")

DIALECTS = ("LK-G3001", "LK-G5001")
DISPLAY_UNITS = ("0.01mm", "0.001mm", "0.0001mm", "0.00001mm", "0.1um", "0.01um")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m cellctl.service.sim_device_server",
        description="The LK-G and ABB protocol fakes in one process, their physics from the twin of the config's [sim].",
    )
    p.add_argument("--config", type=Path, required=True, help="the configuration whose [sim] (and [layout]) the twin is built from")
    p.add_argument("--seed", type=int, default=None, help="the twin's seed (default: sim.seed of the configuration)")
    p.add_argument("--dialect", choices=DIALECTS, default=None,
                   help="the LK-G fake's dialect (default: the config's sim_keyence_lkg laser's, else LK-G5001)")  # fmt: skip
    p.add_argument("--display-unit", choices=DISPLAY_UNITS, default=None,
                   help="the LK-G fake's display unit (default: the config's sim_keyence_lkg laser's, else 0.001mm)")  # fmt: skip
    p.add_argument("--time-scale", type=float, default=None,
                   help="real seconds per simulated second of robot motion (default: sim.time_scale of the configuration)")  # fmt: skip
    p.add_argument("-v", "--verbose", action="store_true")
    return p


def robot_state(fake: FakeController) -> dict[str, Any]:
    """The fake robot's state as its controller sees it (the pose it reports, whether a move runs)."""
    robot = fake.robot
    with robot.lock:
        flange = robot.flange()
        return {
            "moving": robot.moving,
            "motors_on": robot.motors_on,
            "position_mm": list(flange.position_mm),
            "quaternion_wxyz": list(flange.quaternion_wxyz),
            "time_scale": robot.time_scale,
        }


def control(fake: FakeController, line: str) -> dict[str, Any]:
    """One request of the control port: ``state``, or ``time_scale X``; the answer is the robot's state."""
    words = line.split()
    if not words or words == ["state"]:
        return robot_state(fake)
    if words[0] == "time_scale" and len(words) == 2:
        try:
            scale = float(words[1])
        except ValueError:
            scale = float("nan")
        if not (scale > 0 and scale < float("inf")):
            return {"error": f"time_scale must be a number > 0, got {words[1]!r}"}
        with fake.robot.lock:
            fake.robot.time_scale = scale
        return robot_state(fake)
    return {"error": f"unknown request {line.strip()!r}: send 'state' or 'time_scale X'"}


async def _serve(args: argparse.Namespace) -> int:
    try:
        config = load_config(args.config)
    except ConfigError as err:
        print(f"sim_device_server: configuration refused:\n{err}", file=sys.stderr)
        return 2
    if args.time_scale is not None and not args.time_scale > 0:
        print(f"sim_device_server: --time-scale must be > 0, got {args.time_scale}", file=sys.stderr)
        return 2
    laser_dev = config.devices.laser
    dialect = args.dialect or (laser_dev.dialect if isinstance(laser_dev, SimKeyenceLkgDevice) else "LK-G5001")
    unit = args.display_unit or (laser_dev.display_unit if isinstance(laser_dev, SimKeyenceLkgDevice) else "0.001mm")

    cell = SimCell(config.sim, seed=args.seed)
    cell.place_car_body(nominal_world(config.sim.world))
    time_scale = max(cell.time_scale if args.time_scale is None else args.time_scale, 1e-6)

    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)

    lkg = lkg_fake(cell, dialect, unit)
    abb = abb_fake(cell, time_scale=time_scale)
    control_server: asyncio.Server | None = None
    try:
        rapid_port = await abb.start()

        async def answer(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            try:
                line = (await asyncio.wait_for(reader.readline(), 2.0)).decode(errors="replace")
                writer.write((json.dumps(control(abb, line)) + "\n").encode())
                await writer.drain()
            except (asyncio.TimeoutError, OSError):
                pass
            finally:
                writer.close()

        control_server = await asyncio.start_server(answer, "127.0.0.1", 0)
        control_port = int(control_server.sockets[0].getsockname()[1])
        truth = cell.truth()
        ready = {
            "lkg_port": lkg.pty_path,
            "lkg_link": lkg.path,
            "dialect": dialect,
            "display_unit": unit,
            "reference_distance_mm": lkg_reference_mm(cell),
            "displacement_positive": LKG_DISPLACEMENT_POSITIVE,
            "rapid_port": rapid_port,
            "control_port": control_port,
            "time_scale": time_scale,
            "truth": {
                "laser_r": truth.laser_r.tolist(),
                "laser_l": truth.laser_l.tolist(),
                "T_H_C": truth.T_H_C.tolist(),
                "T_B_T": truth.T_B_T.tolist(),
                "seed": cell.seed,
            },
        }
        print(json.dumps(ready), flush=True)
        log.info("serving: LK-G %s on %s, RAPID on 127.0.0.1:%d", dialect, lkg.pty_path, rapid_port)
        await stop.wait()
        log.info("stopping")
    finally:
        if control_server is not None:
            control_server.close()
            await control_server.wait_closed()
        await abb.aclose()
        lkg.stop()
    return 0


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")  # fmt: skip
    return asyncio.run(_serve(args))


if __name__ == "__main__":
    sys.exit(main())
