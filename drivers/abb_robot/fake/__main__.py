"""``python -m abb_robot.fake``: run the fake ABB controller in its own process.

It prints one line ``READY rapid_port=<P> egm_port=<Q|none>`` on stdout once it serves, then
runs until SIGINT or SIGTERM.
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import logging
import signal
import sys
from dataclasses import fields

from abb_robot.egm.peer_core import set_realtime_priority
from abb_robot.fake.controller import FakeController, FakeControllerConfig
from abb_robot.fake.egm_robot import EgmDynamics
from abb_robot.fake.model import SimpleArmModel


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m abb_robot.fake", description=__doc__)
    p.add_argument("--rapid-host", default="127.0.0.1", help="address the line server binds (default 127.0.0.1)")
    p.add_argument("--rapid-port", type=int, required=True, help="TCP port of the line server (0 = any free port)")
    p.add_argument("--egm-host", dest="egm_sensor_host", metavar="EGM_HOST", default="127.0.0.1",
                   help="sensor (PC) address EGM datagrams go to")
    p.add_argument("--egm-port", dest="egm_sensor_port", metavar="EGM_PORT", type=int, default=None,
                   help="sensor UDP port EGM datagrams go to (omit: no EGM)")
    p.add_argument("--egm-period-ms", type=float, default=4.0, help="EGM cycle (default 4 ms)")
    p.add_argument("--egm-comm-timeout-s", type=float, default=1.0, help="EGM CommTimeout (default 1 s)")
    p.add_argument("--egm-loss", dest="egm_loss_out", metavar="EGM_LOSS", type=float, default=0.0,
                   help="fraction of EgmRobot datagrams dropped (seeded)")
    p.add_argument("--egm-reply-loss", dest="egm_loss_in", metavar="EGM_REPLY_LOSS", type=float, default=0.0,
                   help="fraction of EgmSensor replies dropped (seeded)")
    p.add_argument("--seed", type=int, default=0, help="seed of the loss and noise generators")
    p.add_argument("--repeatability-mm", type=float, default=0.03, help="one-sigma position noise per axis")
    p.add_argument("--idle-timeout-s", type=float, default=10.0, help="drop a client silent this long")
    p.add_argument("--time-scale", type=float, default=1.0, help="multiply motion durations (default 1)")
    p.add_argument("--gripper-settle-s", type=float, default=0.5,
                   help="GRIP waits this long after switching the vacuum (default 0.5 s, times --time-scale)")
    p.add_argument("--stats-file", default=None, help="write each EGM session's statistics there as JSON")
    p.add_argument("--rt-priority", dest="egm_rt_priority", metavar="RT_PRIORITY", type=int, default=None,
                   help="SCHED_FIFO priority of the EGM thread (1..99)")
    p.add_argument("-v", "--verbose", action="store_true")
    return p


async def _main(args: argparse.Namespace) -> None:
    # The parser's destinations are named after the config's fields: those given are passed on as they are.
    given = {f.name: getattr(args, f.name) for f in fields(FakeControllerConfig) if hasattr(args, f.name)}
    config = FakeControllerConfig(
        **given, egm=EgmDynamics(period_s=args.egm_period_ms / 1000.0, comm_timeout_s=args.egm_comm_timeout_s)
    )
    if config.egm_rt_priority is not None:
        # The EGM thread shares the interpreter lock with this (asyncio) thread: were this one
        # preempted by ordinary load while it holds the lock, the EGM thread would wait for it.
        refused = set_realtime_priority(max(1, config.egm_rt_priority - 1))
        if refused:
            print(f"abb_robot.fake: {refused}", file=sys.stderr)
    controller = FakeController(config, SimpleArmModel(repeatability_mm=args.repeatability_mm, seed=args.seed))
    port = await controller.start()
    # Everything loaded so far lives as long as the process: keep it out of the collector's way,
    # so a full collection does not stall the 4 ms EGM cycle.
    gc.freeze()
    egm = "none" if controller.egm is None else str(controller.egm.local_address[1])
    print(f"READY rapid_port={port} egm_port={egm}", flush=True)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    await stop.wait()
    await controller.aclose()


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, stream=sys.stderr)
    try:
        asyncio.run(_main(args))
    except ValueError as exc:
        print(f"abb_robot.fake: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
