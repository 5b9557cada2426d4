"""EGM: the peer's child process dying (the OOM killer, a crash in the protobuf runtime) is never silent.

The child is killed with SIGKILL, found and checked through /proc (the OS, not the driver's objects). The
position stream's controller is the stand-in process of _abb_egm_cell.py (hand-encoded
datagrams, logged as sent); the fine correction runs against the fake controller.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import os
import signal
import time
from pathlib import Path

import pytest

from _abb_testkit import fake_and_robot
from abb_robot.fake import DEFAULT_HOME
from cellctl.ports import CartesianPose, DeviceDisconnected
from _abb_egm_cell import check_all_sent, standin_cell, stream_x


def _egm_children() -> set[int]:
    """PIDs of this process's live EGM peer children, as the OS lists them (zombies left out)."""
    me, found = os.getpid(), set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            state, ppid = (entry / "stat").read_text().rsplit(")", 1)[1].split()[:2]
            cmdline = (entry / "cmdline").read_bytes()
        except (OSError, ValueError):
            continue  # gone meanwhile
        if int(ppid) == me and state != "Z" and b"abb_robot.egm._peer_child" in cmdline:
            found.add(int(entry.name))
    return found


def _has_exited(pid: int) -> bool:
    """The child can be waited for (the OS's answer, the child left unreaped): a process on its way out has dropped
    its command line already, and a killed leader shows as a zombie in /proc while its other threads still exit; in
    both its parent's poll still finds it running."""
    try:
        return os.waitid(os.P_PID, pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is not None
    except ChildProcessError:  # reaped already
        return True


async def _kill_the_egm_child() -> int:
    (pid,) = _egm_children()
    os.kill(pid, signal.SIGKILL)
    deadline = time.monotonic() + 5.0
    while not _has_exited(pid) and time.monotonic() < deadline:
        await asyncio.sleep(0.01)
    assert _has_exited(pid) and pid not in _egm_children()
    return pid


def _secondstream_x(log: Path) -> list[float]:
    """The x of the datagrams the controller sent in its second stream (each stream starts at seqno 0)."""
    rows = [json.loads(line) for line in log.read_text().splitlines()]
    starts = [i for i, r in enumerate(rows) if r["seq"] == 0]
    return [r["x"] for r in rows[starts[1] :]]


async def test_a_killed_egm_process_is_started_again_for_the_next_stream(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    async with standin_cell(tmp_path, isolation="process") as cell:
        assert len(await stream_x(cell, 0.3)) > 50
        killed = await _kill_the_egm_child()
        with caplog.at_level(logging.WARNING, logger="abb_robot.egm.peer"):
            got = await stream_x(cell, 0.4)
        check_all_sent(got, _secondstream_x(cell.log))
        assert _egm_children() - {killed}, "no EGM process runs"
        said = " ".join(r.getMessage() for r in caplog.records)
        assert f"EGM process (pid {killed}) died (killed by signal 9 (SIGKILL)); starting it again" in said


async def test_an_egm_process_dying_during_a_stream_fails_the_stream_naming_it(tmp_path: Path) -> None:
    async with standin_cell(tmp_path, isolation="process") as cell:
        await cell.robot.start_stream(timeout_s=5.0)
        await asyncio.sleep(0.2)
        killed = await _kill_the_egm_child()
        await asyncio.sleep(0.1)
        with pytest.raises(DeviceDisconnected, match=rf"EGM process \(pid {killed}\) died .*during the position stream"):
            await cell.robot.stop_stream(timeout_s=5.0)
        got = await stream_x(cell, 0.3)  # the next stream starts the process again
        check_all_sent(got, _secondstream_x(cell.log))


async def test_an_egm_process_dying_during_a_correction_fails_it_naming_it() -> None:
    x, y, z = DEFAULT_HOME.position_mm
    target = CartesianPose((x + 2.0, y, z), DEFAULT_HOME.quaternion_wxyz)
    async with fake_and_robot(egm=True, robot_kw={"egm_cond_time_s": 1.5}) as (fake, robot):
        await robot.egm.start(timeout_s=30.0)  # type: ignore[union-attr]
        correction = asyncio.create_task(
            robot.correct_to(target, tolerance_mm=0.1, tolerance_rad=math.radians(0.05), timeout_s=10.0))
        await asyncio.sleep(0.5)  # converging, holding the band for 1.5 s before the controller ends it
        assert not correction.done()
        killed = await _kill_the_egm_child()
        t_killed = time.monotonic()
        with pytest.raises(DeviceDisconnected, match=rf"EGM process \(pid {killed}\) died"):
            await correction
        assert time.monotonic() - t_killed < 0.4  # before the controller's EGM timeout (0.5 s) would tell
        got = await robot.correct_to(target, tolerance_mm=0.1, tolerance_rad=math.radians(0.05), timeout_s=10.0)
        assert math.dist(got.position_mm, target.position_mm) <= 0.1  # the next correction starts it again
        assert math.dist(fake.robot.tcp().position_mm, target.position_mm) <= 0.1
