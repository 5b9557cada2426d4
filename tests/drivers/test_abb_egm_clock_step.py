"""EGM position stream against the fake controller: a step of the controller's clock (header.tm) breaks the stream.

The stream maps tm to the host's clock with one offset; a step of the controller's clock mid-stream
would put every sample on one side of it at a wrong instant. Truth is the fake's own record of the
stamps it sent (its tm steps) and of the seqnos it produced, never the driver's objects.
"""

from __future__ import annotations

import asyncio
import time
from typing import Any

import numpy as np
import pytest

from _abb_testkit import fake_and_robot
from abb_robot.egm import egm_pb2 as pb
from abb_robot.fake import FakeController
from cellctl.ports import DeviceProtocolError

pytestmark = pytest.mark.realtime  # the fake streams on the host's clock


async def _latest_goes_none(robot: Any, timeout_s: float) -> bool:
    """Poll latest() as the sweep's supervision does; True once it gives None."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if robot.latest() is None:
            return True
        await asyncio.sleep(0.004)
    return False


@pytest.mark.parametrize(("step_s", "isolation"), [(0.030, "thread"), (0.030, "process"), (-0.030, "thread")])
async def test_a_step_of_the_controllers_clock_refuses_the_stream(step_s: float, isolation: str) -> None:
    async with fake_and_robot(egm=True, fake_kw={"time_scale": 1.0}, robot_kw={"egm_isolation": isolation}) as (fake, robot):
        assert fake.egm is not None and robot.egm is not None
        await robot.egm.start(timeout_s=10.0)
        await robot.start_stream(timeout_s=5.0)
        await asyncio.sleep(0.4)
        assert robot.latest() is not None  # a healthy stream so far
        fake.egm.stream.clock.boot -= step_s  # tm reads step_s more from now on
        assert await _latest_goes_none(robot, 1.0), "latest() still gives samples after the controller's clock stepped"
        with pytest.raises(DeviceProtocolError, match="EGM clock") as info:
            await robot.stop_stream(timeout_s=2.0)
        fs = fake.egm_stream_stats
        assert fs is not None
        steps = np.diff(np.asarray(fs.tm, dtype=float))
        assert steps.max() >= 25 if step_s > 0 else steps.min() <= -20  # truth: the fake's tm did step
        assert ("forward" if step_s > 0 else "went back") in str(info.value)
        assert robot.stream_stats.clock_break and robot.latest() is None
        # The next stream is a new one: it runs clean.
        await robot.start_stream(timeout_s=5.0)
        await asyncio.sleep(0.3)
        assert len(await robot.stop_stream(timeout_s=2.0)) > 20


class _SeqOffset:
    """Stands in for the fake's EGM socket: every datagram's seqno shifted (the stream starts near the u32 wrap)."""

    def __init__(self, sock: Any, offset: int) -> None:
        self.sock, self.offset = sock, offset

    def sendto(self, data: bytes, addr: tuple[str, int]) -> int:
        m = pb.EgmRobot()
        m.ParseFromString(data)
        m.header.seqno = (m.header.seqno + self.offset) & 0xFFFFFFFF
        return int(self.sock.sendto(m.SerializeToString(), addr))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.sock, name)


def _shift_seqnos(fake: FakeController, offset: int) -> None:
    runner = fake.egm.stream  # type: ignore[union-attr]
    runner._args = (_SeqOffset(runner._args[0], offset), *runner._args[1:])


async def test_lost_counts_gaps_from_the_first_seqno_seen() -> None:
    async with fake_and_robot(egm=True, fake_kw={"time_scale": 1.0, "egm_loss_out": 0.05, "seed": 3},
                              robot_kw={"egm_isolation": "thread"}) as (fake, robot):
        _shift_seqnos(fake, (1 << 32) - 100)  # the first seqno sent is 2**32 - 100; it wraps 0.4 s in
        await robot.start_stream(timeout_s=3.0)
        await asyncio.sleep(1.0)
        await robot.stop_stream(timeout_s=2.0)
        fs = fake.egm_stream_stats
        assert fs is not None and fs.dropped_out > 0
        rec = robot.stream_records()
        first, last = ((int(s) - (1 << 32) + 100) % (1 << 32) for s in (rec.seqno[0], rec.seqno[-1]))  # the fake's seqnos
        truth = sum(1 for s in fs.dropped_seqnos if first < s < last)
        st = robot.stream_stats
        assert st.lost == truth, (st.lost, truth)
        assert st.gap_events <= st.lost and st.received == len(rec.seqno) and not st.clock_break
