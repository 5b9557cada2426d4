"""A cell for the EGM tests: the controller stand-in process (``_abb_egm_standin.py``) and a connected robot,
other senders on other loopback addresses, and the checks of a stream against what the controller sent."""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import subprocess
import sys
import threading
import time
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from _abb_egm_wire import egm_robot
from _abb_testkit import LOOPBACK, free_udp_port
from abb_robot import AbbRobot, AbbRobotSettings

STANDIN = Path(__file__).with_name("_abb_egm_standin.py")
STRAY, NATTED = "127.0.0.2", "127.0.0.3"


@dataclass
class Cell:
    """A connected robot, its EGM port, and the stand-in's log of the datagrams it sent."""

    robot: AbbRobot
    egm_port: int
    log: Path

    def sent_x(self) -> list[float]:
        """The x (mm) of every datagram the controller sent, in order."""
        return [json.loads(line)["x"] for line in self.log.read_text().splitlines()]


@contextlib.asynccontextmanager
async def standin_cell(tmp_path: Path, *standin_args: str, isolation: str = "thread") -> AsyncIterator[Cell]:
    """The stand-in controller (its options ``standin_args``) and a robot connected to it, its EGM peer started."""
    egm_port = free_udp_port()
    log = tmp_path / "sent.jsonl"
    proc = subprocess.Popen([sys.executable, str(STANDIN), "--egm", str(egm_port), "--log", str(log), *standin_args],
                            stdout=subprocess.PIPE)
    assert proc.stdout is not None
    ready = proc.stdout.readline().split()
    robot = None
    try:
        assert ready[:1] == [b"ready"], ready
        robot = AbbRobot(AbbRobotSettings(host=LOOPBACK, rapid_port=int(ready[1]), egm_port=egm_port,
                                          egm_bind_host=LOOPBACK, egm_isolation=isolation))  # type: ignore[arg-type]
        await robot.connect(timeout_s=5.0)
        await robot.egm.start(timeout_s=30.0)  # type: ignore[union-attr]
        yield Cell(robot, egm_port, log)
    finally:
        if robot is not None:
            await robot.close()
        proc.kill()
        proc.wait()
        proc.stdout.close()


@contextlib.contextmanager
def stray_sender(port: int, *, src: str = STRAY, count: int | None = None) -> Iterator[threading.Event]:
    """Another host sending EgmRobot to the EGM port every 4 ms: ``count`` of them (the block ends when they are
    sent), or until the block ends."""
    done = threading.Event()

    def send() -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind((src, 0))
            seq = 0
            while not done.is_set() and (count is None or seq < count):
                s.sendto(egm_robot(seq, 1000 + 4 * seq, 0.0), (LOOPBACK, port))
                seq += 1
                time.sleep(0.004)

    thread = threading.Thread(target=send, daemon=True)
    thread.start()
    try:
        yield done
    finally:
        if count is None:
            done.set()
        thread.join()


async def until(condition: Callable[[], bool], timeout_s: float = 5.0) -> None:
    """Wait for what was sent to show (a process peer publishes its status after it replied)."""
    deadline = time.monotonic() + timeout_s
    while not condition() and time.monotonic() < deadline:
        await asyncio.sleep(0.01)


async def stream_x(cell: Cell, seconds: float = 0.4) -> list[float]:
    """Run a position stream for ``seconds``; the x (mm) of its samples, in order."""
    await cell.robot.start_stream(timeout_s=5.0)
    await asyncio.sleep(seconds)
    return [round(s.pose.position_mm[0], 3) for s in await cell.robot.stop_stream(timeout_s=5.0)]


def check_all_sent(got: list[float], sent: list[float]) -> None:
    """Every datagram the controller sent, once each and in order (the last two may still be on their way)."""
    sent = [round(x, 3) for x in sent]
    assert got == sent[: len(got)], "a sample came twice, out of order, or from another sender"
    assert len(got) >= len(sent) - 2 and len(sent) > 50
