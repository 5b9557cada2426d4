"""EGM position stream: the STREAM verb on the fake, its datagrams, and AbbRobot as a cellctl.ports.PoseStream.

Truth is the fake robot's own motion as a function of time (the ``Motion`` the fake's robot runs,
evaluated at an instant) and the fake's record of when it read each datagram's pose, never the
driver's objects.
"""

from __future__ import annotations

import asyncio
import math
import socket
import time
from pathlib import Path
from collections.abc import Callable

import numpy as np
import pytest

from _abb_testkit import LOOPBACK, fake_and_robot, start_fake
from abb_robot import EgmPeer, EgmPeerSettings
from abb_robot import protocol as P
from abb_robot.egm import egm_pb2 as pb
from abb_robot.egm.peer_core import F_FB_TIME, F_GEN, F_POS, F_RX, F_SEQNO, F_TM
from abb_robot.fake import DEFAULT_HOME, EgmDynamics, FakeController
from abb_robot.fake.robot import Motion
from abb_robot.unit_quaternion import angle_between
from cellctl.ports import CartesianPose, DeviceRejected, MotionRequest, PoseStream
from test_abb_fake_server import raw_client

pytestmark = pytest.mark.realtime  # the fake streams on the host's clock; its timing is scored
C = 1000.0
"""The cell's clock in these tests runs this far ahead of time.monotonic (s)."""
TIMING_BUDGET_S = 0.0015
"""How far a sample's instant may be from when the fake read its pose: tm is the whole ms nearest to
that read (0.5 ms), the read itself lies within 0.2 ms (the fake retries wider ones), and the mapped
instant keeps the least transport delay of the stream (loopback: well under 0.5 ms)."""
ROT_Z_4DEG = (math.cos(math.radians(2.0)), 0.0, 0.0, math.sin(math.radians(2.0)))


def cell_clock() -> float:
    return time.monotonic() + C


def _qmul(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, float, float, float]:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return (w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2)


def _record_motions(fake: FakeController) -> list[Motion]:
    """The moves the fake's robot begins from now on (its public begin_motion, wrapped)."""
    motions: list[Motion] = []
    begin = fake.robot.begin_motion

    def recording(flange_target: CartesianPose, linear: bool) -> Motion:
        motion = begin(flange_target, linear)
        motions.append(motion)
        return motion

    fake.robot.begin_motion = recording  # type: ignore[method-assign]
    return motions


def _truth_at(motions: list[Motion], t: float) -> CartesianPose:
    """The fake robot's flange (tool0 in wobj0: the TCP) at monotonic instant ``t``, from its motions."""
    started = [m for m in motions if m.t0 <= t]
    return (started[-1] if started else motions[0]).pose_at(t)


def _peak_rates(motion: Motion) -> tuple[float, float]:
    """The motion's peak speed (mm/s) and turn rate (rad/s), by finite differences over 1 ms."""
    ts = np.arange(motion.t0 - 0.01, motion.t0 + motion.duration_s + 0.01, 0.001)
    poses = [motion.pose_at(float(t)) for t in ts]
    v = max(math.dist(a.position_mm, b.position_mm) for a, b in zip(poses, poses[1:])) / 0.001
    w = max(angle_between(a.quaternion_wxyz, b.quaternion_wxyz) for a, b in zip(poses, poses[1:])) / 0.001
    return v, w


def _by_seqno(fake: FakeController, seqnos: np.ndarray) -> np.ndarray:
    """When the fake read the pose of each datagram (time.monotonic, s), by seqno."""
    stats = fake.egm_stream_stats
    assert stats is not None
    sampled = dict(zip(stats.seqnos, stats.sampled_at))
    return np.array([sampled[int(s)] for s in seqnos])


async def _wait_until(condition: Callable[[], object], timeout_s: float = 3.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition() and time.monotonic() < deadline:
        await asyncio.sleep(0.01)


# ------------------------------------------------------------------------------------------------
# AbbRobot as a PoseStream, against the fake controller (no twin)


@pytest.mark.parametrize("isolation", ["thread", "process"])
async def test_stream_during_a_movel_follows_the_robots_own_motion(isolation: str) -> None:
    async with fake_and_robot(egm=True, fake_kw={"time_scale": 1.0}, robot_kw={"egm_isolation": isolation},
                              clock=cell_clock) as (fake, robot):
        assert isinstance(robot, PoseStream)
        motions = _record_motions(fake)
        assert fake.egm is not None and robot.egm is not None
        await robot.egm.start(timeout_s=10.0)  # a process takes a while: the wrap below is to come in the stream
        fake.egm.stream.clock.boot = time.monotonic() - (2**32 - 300) / 1000.0  # tm wraps 0.3 s from now
        x, y, z = DEFAULT_HOME.position_mm
        target = CartesianPose((x + 150.0, y + 40.0, z - 20.0), _qmul(ROT_Z_4DEG, DEFAULT_HOME.quaternion_wxyz))
        t_start = cell_clock()
        await robot.start_stream(timeout_s=5.0)
        assert robot.latest() is None or robot.latest().t_s >= t_start  # type: ignore[union-attr]
        await asyncio.sleep(0.1)
        replied = robot.egm.stats().replied  # type: ignore[union-attr]
        await robot.move(MotionRequest(target, speed_mm_s=250.0, speed_deg_s=20.0), timeout_s=5.0)
        await asyncio.sleep(0.1)
        samples = await robot.stop_stream(timeout_s=2.0)
        t_stop = cell_clock()
        fs = fake.egm_stream_stats
        assert fs is not None and fs.dropped_out == 0 and len(motions) == 1
        assert len(samples) == fs.sent > 150  # all that left arrived (the move takes some 0.7 s)
        assert robot.egm.stats().replied == replied  # type: ignore[union-attr]  # the sensor sends nothing back
        t = np.array([s.t_s for s in samples])
        assert np.all(np.diff(t) > 0) and t_start < t[0] and t[-1] < t_stop  # on the given clock, in order
        rec = robot.stream_records()
        assert np.any(np.diff(rec.tm_ms) < 0)  # the controller's u32 ms clock wrapped meanwhile
        # Whole ms apart (tm, the controller's ms clock, not when a datagram arrived), mostly 4 ms: the
        # controller's grid; a datagram the in-process fake read late is stamped when it read it.
        steps_ms = np.round(np.diff(t) * 1000.0, 6)
        assert np.all(steps_ms == np.round(steps_ms)) and np.all(steps_ms >= 1.0), steps_ms
        assert np.bincount(steps_ms.astype(int)).argmax() == 4, np.unique(steps_ms, return_counts=True)
        # On the given clock: each instant is when the fake read that datagram's pose, plus C.
        err = t - C - _by_seqno(fake, rec.seqno)
        assert np.all(np.abs(err) <= TIMING_BUDGET_S), (err.min(), err.max())
        # Every pose is the robot's own motion at the sample's instant.
        v_peak, w_peak = _peak_rates(motions[0])
        assert v_peak > 150.0 and w_peak > math.radians(5.0)
        for s in samples:
            truth = _truth_at(motions, s.t_s - C)
            assert math.dist(s.pose.position_mm, truth.position_mm) <= v_peak * TIMING_BUDGET_S + 1e-6
            assert angle_between(s.pose.quaternion_wxyz, truth.quaternion_wxyz) <= w_peak * TIMING_BUDGET_S + 1e-7
        assert math.dist(samples[0].pose.position_mm, samples[-1].pose.position_mm) > 150.0  # it did move
        st = robot.stream_stats
        assert st.received == len(samples) and st.lost == 0 and st.gap_events == 0 and st.stamp == "tm"
        assert st.clock_offset_s == pytest.approx(C, abs=1e-3)
        assert robot.latest() is None  # no stream runs now


@pytest.mark.parametrize("isolation", ["thread", "process"])
async def test_tm_mapping_removes_injected_receive_jitter(isolation: str) -> None:
    async with fake_and_robot(egm=True, fake_kw={"egm_stream_jitter_s": 0.003, "seed": 4},
                              robot_kw={"egm_isolation": isolation}, clock=cell_clock) as (fake, robot):
        await robot.start_stream(timeout_s=5.0)
        await asyncio.sleep(0.8)
        samples = await robot.stop_stream(timeout_s=2.0)
        rec = robot.stream_records()
        sampled = _by_seqno(fake, rec.seqno)
        raw = rec.received_s - sampled  # transport delay: up to 3 ms of injected jitter, plus the host's
        mapped = rec.t_s - C - sampled
        assert len(samples) > 150
        assert np.ptp(raw) > 0.002, np.ptp(raw)
        assert np.ptp(mapped) < 0.00125, np.ptp(mapped)  # the whole-ms stamps, and the read window
        assert np.all(np.abs(mapped) <= TIMING_BUDGET_S)
        st = robot.stream_stats
        assert st.delay_max_s > 0.002 and st.delay_p50_s > 0.0005  # what the mapping took out


async def test_five_percent_loss_gives_fewer_samples_and_counted_gaps() -> None:
    async with fake_and_robot(egm=True, fake_kw={"egm_loss_out": 0.05, "seed": 9},
                              robot_kw={"egm_isolation": "thread"}) as (fake, robot):
        await robot.start_stream(timeout_s=3.0)
        await asyncio.sleep(1.2)
        samples = await robot.stop_stream(timeout_s=2.0)
        fs = fake.egm_stream_stats
        assert fs is not None
        produced = len(fs.seqnos)
        assert len(samples) == fs.sent == produced - fs.dropped_out
        assert 0.02 * produced < fs.dropped_out < 0.09 * produced
        last = int(robot.stream_records().seqno[-1])
        st = robot.stream_stats
        # Every datagram dropped before the last one received shows up as a seqno gap.
        assert st.lost == sum(1 for s in fs.dropped_seqnos if s < last) and st.lost > 0
        assert 0 < st.gap_events <= st.lost and st.received == len(samples)
        assert st.max_interval_s >= 0.008  # a gap spans at least two periods


async def test_a_stream_cut_mid_path_goes_stale_while_stop_returns_what_came() -> None:
    async with fake_and_robot(egm=True, fake_kw={"time_scale": 1.0}, robot_kw={"egm_isolation": "thread"},
                              clock=cell_clock) as (fake, robot):
        x, y, z = DEFAULT_HOME.position_mm
        await robot.start_stream(timeout_s=3.0)
        move = asyncio.create_task(robot.move(
            MotionRequest(CartesianPose((x + 200.0, y, z), DEFAULT_HOME.quaternion_wxyz), speed_mm_s=200.0),
            timeout_s=5.0))
        await asyncio.sleep(0.4)
        fake.cut_egm_stream()  # the network dies; RAPID still streams and moves
        await asyncio.sleep(0.05)
        first = robot.latest()
        assert first is not None
        age = cell_clock() - first.t_s
        await asyncio.sleep(0.3)
        again = robot.latest()
        assert again == first and cell_clock() - again.t_s > age + 0.25  # stale: its age grows
        assert not move.done() and fake.server.streaming  # type: ignore[union-attr]
        await move  # the move itself ends as asked
        samples = await robot.stop_stream(timeout_s=2.0)
        fs = fake.egm_stream_stats
        assert fs is not None and fs.cut_at is not None and fs.cut_out > 50
        assert len(samples) == fs.sent > 50 and samples[-1].t_s - C <= fs.cut_at + TIMING_BUDGET_S
        assert samples[-1] == first


async def test_stop_and_a_lost_link_end_the_stream() -> None:
    async with fake_and_robot(egm=True, robot_kw={"egm_isolation": "thread"}) as (fake, robot):
        server = fake.server
        assert server is not None
        await robot.start_stream(timeout_s=3.0)
        await _wait_until(lambda: robot.latest() is not None)
        # The module refuses STREAM (BUSY) until the motion task has decelerated after a STOP: the driver
        # knows STOP ended the stream and sends no STREAM 0 (here every STREAM after the STOP is refused).
        refused: list[int] = []

        async def decelerating(s: object, rid: int, on: int) -> None:
            refused.append(on)
            await server._err(s, rid, P.ErrorCode.BUSY, "motion running")  # type: ignore[arg-type]

        await robot.stop(timeout_s=1.0)  # STOP ends the stream too
        assert not server.streaming and robot.latest() is None
        server._do_stream = decelerating  # type: ignore[method-assign]
        samples = await robot.stop_stream(timeout_s=1.0)
        assert refused == []
        del server._do_stream
        assert samples and len(samples) == fake.egm_stream_stats.sent  # type: ignore[union-attr]
        await robot.start_stream(timeout_s=3.0)
        await _wait_until(lambda: robot.latest() is not None)
        fake.drop_client()  # a lost link ends it
        await _wait_until(lambda: not server.streaming)
        assert not server.streaming
        samples = await robot.stop_stream(timeout_s=2.0)  # still returns what came
        assert samples and len(samples) == fake.egm_stream_stats.sent  # type: ignore[union-attr]
        await robot.ping(timeout_s=2.0)  # reconnected


async def test_restart_drops_the_previous_collection_and_moving_refuses_start_and_stop() -> None:
    async with fake_and_robot(egm=True, fake_kw={"time_scale": 0.5}, robot_kw={"egm_isolation": "thread"}) as (
        fake, robot,
    ):
        x, y, z = DEFAULT_HOME.position_mm
        await robot.start_stream(timeout_s=3.0)
        await asyncio.sleep(0.2)
        t_restart = time.monotonic()
        await robot.start_stream(timeout_s=3.0)  # not stopped: the stream restarts at seqno 0
        await asyncio.sleep(0.2)
        samples = await robot.stop_stream(timeout_s=2.0)
        rec = robot.stream_records()
        assert rec.seqno[0] == 0 and np.all(np.diff(rec.seqno) == 1)
        assert samples[0].t_s > t_restart and len(samples) == fake.egm_stream_stats.sent  # type: ignore[union-attr]
        move = asyncio.create_task(robot.move(
            MotionRequest(CartesianPose((x + 100.0, y, z), DEFAULT_HOME.quaternion_wxyz)), timeout_s=5.0))
        await asyncio.sleep(0.05)
        with pytest.raises(DeviceRejected, match="STREAM 1 refused: the robot is moving; start the") as info:
            await robot.start_stream(timeout_s=2.0)
        assert info.value.code == "110 BUSY" and not robot.stream_stats.received  # nothing collected
        await move
        with pytest.raises(DeviceRejected, match="no position stream was started"):
            await robot.stop_stream(timeout_s=1.0)
        await robot.start_stream(timeout_s=2.0)
        move = asyncio.create_task(robot.move(
            MotionRequest(CartesianPose((x, y, z), DEFAULT_HOME.quaternion_wxyz)), timeout_s=5.0))
        await asyncio.sleep(0.05)
        with pytest.raises(DeviceRejected, match="STREAM 0 refused: the robot is moving"):
            await robot.stop_stream(timeout_s=2.0)
        before = robot.latest()
        await asyncio.sleep(0.05)
        after = robot.latest()
        assert before is not None and after is not None and after.t_s > before.t_s  # it goes on, collected
        await move
        assert len(await robot.stop_stream(timeout_s=2.0)) == fake.egm_stream_stats.sent  # type: ignore[union-attr]


async def test_without_egm_the_stream_is_refused_naming_the_setting() -> None:
    async with fake_and_robot(egm=False) as (fake, robot):
        with pytest.raises(DeviceRejected, match="set egm_port in the robot's settings"):
            await robot.start_stream(timeout_s=1.0)
        with pytest.raises(DeviceRejected, match="no position stream was started"):
            await robot.stop_stream(timeout_s=1.0)
        assert robot.latest() is None
        assert not any("STREAM" in line for line in fake.server.lines_received)  # type: ignore[union-attr]


async def test_a_stream_and_a_guidance_session_exclude_each_other() -> None:
    async with fake_and_robot(egm=True, fake_kw={"egm": EgmDynamics(comm_timeout_s=1.0)},
                              robot_kw={"egm_isolation": "thread"}) as (fake, robot):
        session = await robot.start_egm_session(band_mm=0.01, band_deg=0.01, cond_s=30.0, timeout_s=3.0)
        with pytest.raises(DeviceRejected, match="guidance session .* runs") as info:
            await robot.start_stream(timeout_s=1.0)
        assert info.value.code == "110 BUSY"
        await robot.stop(timeout_s=1.0)
        with pytest.raises(Exception, match="code 140 STOPPED"):
            await asyncio.wait_for(session, 2.0)
        await robot.start_stream(timeout_s=2.0)
        with pytest.raises(DeviceRejected, match="the position stream runs; stop it first"):
            await robot.correct_to(DEFAULT_HOME, tolerance_mm=0.1, tolerance_rad=0.01, timeout_s=2.0)
        with pytest.raises(DeviceRejected, match="the position stream runs"):
            await robot.start_egm_session(band_mm=0.1, band_deg=0.1, cond_s=1.0, timeout_s=2.0)
        await asyncio.sleep(0.1)
        assert await robot.stop_stream(timeout_s=2.0)
        assert fake.last_egm_stats is not None and fake.last_egm_stats.end == "stopped"  # only the first session ran


@pytest.mark.parametrize("isolation", ["thread", "process"])
async def test_peer_collects_a_stream_without_answering(isolation: str) -> None:
    peer = EgmPeer(EgmPeerSettings(port=0, bind_host=LOOPBACK, isolation=isolation))  # type: ignore[arg-type]
    await peer.start(timeout_s=10.0)
    ctl = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ctl.bind((LOOPBACK, 0))
    ctl.settimeout(0.2)

    def datagram(seq: int, tm: int) -> bytes:
        m = pb.EgmRobot()
        m.header.seqno, m.header.tm, m.header.mtype = seq, tm, pb.EgmHeader.MSGTYPE_DATA
        m.feedBack.time.sec, m.feedBack.time.usec = divmod(tm * 1000, 1_000_000)
        c = m.feedBack.cartesian
        c.pos.x, c.pos.y, c.pos.z = 1000.0 + seq, 0.0, 1500.0
        c.orient.u0, c.orient.u1, c.orient.u2, c.orient.u3 = 1.0, 0.0, 0.0, 0.0
        return m.SerializeToString()

    try:
        ctl.sendto(datagram(40, 1000), (LOOPBACK, peer.port))  # guidance: answered
        ctl.recvfrom(4096)
        since = peer.stream_count()
        gen = peer.begin_stream()
        t0 = time.monotonic()
        for seq, tm in ((7, 2000), (8, 2004), (10, 2012)):  # a new stream (not from 0 here), one datagram lost
            ctl.sendto(datagram(seq, tm), (LOOPBACK, peer.port))
        with pytest.raises(socket.timeout):
            ctl.recvfrom(4096)  # nothing answered
        await _wait_until(lambda: peer.stream_count() >= since + 3)
        rows, count, overwritten = peer.stream_records(since)
        assert count == since + 3 and overwritten == 0 and np.all(rows[:, F_GEN] == gen)
        assert rows[:, F_SEQNO].tolist() == [7, 8, 10] and rows[:, F_TM].tolist() == [2000, 2004, 2012]
        assert rows[:, F_FB_TIME].tolist() == pytest.approx([2.0, 2.004, 2.012])
        assert np.all((rows[:, F_RX] > t0) & (rows[:, F_RX] < time.monotonic())) and np.all(np.diff(rows[:, F_RX]) >= 0)
        assert rows[:, F_POS].tolist() == [1007.0, 1008.0, 1010.0]
        stats = peer.stats()
        assert stats.sessions == 2 and stats.lost == 1  # the stream began a session of its own
        peer.end_stream()
        ctl.sendto(datagram(11, 2016), (LOOPBACK, peer.port))
        ctl.settimeout(1.0)
        ctl.recvfrom(4096)  # answered again
        assert peer.stream_records(count)[0].shape[0] == 0
    finally:
        ctl.close()
        await peer.close()


# ------------------------------------------------------------------------------------------------
# The fake's line server and datagrams, byte by byte


def _receive(sock: socket.socket) -> pb.EgmRobot:
    data, _ = sock.recvfrom(4096)
    return pb.EgmRobot.FromString(data)


async def test_fake_serves_stream_as_the_module_does() -> None:
    sensor = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sensor.bind((LOOPBACK, 0))
    sensor.settimeout(1.0)
    tool = CartesianPose((0.0, 0.0, 250.0), (1.0, 0.0, 0.0, 0.0))
    wobj = CartesianPose((1000.0, -200.0, 300.0), (math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)))
    fake = start_fake(egm_sensor_port=sensor.getsockname()[1], time_scale=0.2, egm_uptime_ms=123_456,
                      tools={"tPen": tool}, wobjs={"wTable": wobj})
    try:
        async with raw_client(fake) as c:
            assert (await c.ask("1 HELLO 1"))[0].startswith("1 OK 1 ")
            assert await c.ask("2 STREAM 2") == ["2 ERR 122 STREAM needs 1 (start) or 0 (stop)"]
            assert await c.ask("3 STREAM 1.0") == ["3 ERR 100 on is not an integer"]
            assert await c.ask("4 TOOL tPen") == ["4 OK tPen"]
            assert await c.ask("5 WOBJ wTable") == ["5 OK wTable"]
            assert await c.ask("6 STREAM 1") == ["6 OK 1"]
            first = await asyncio.to_thread(_receive, sensor)
            assert first.header.seqno == 0 and first.header.mtype == pb.EgmHeader.MSGTYPE_DATA
            assert 123_456 <= first.header.tm < 133_456  # the controller's uptime clock, ms
            assert abs(first.feedBack.time.sec + 1e-6 * first.feedBack.time.usec - time.time()) < 5  # UNIX time (egm.proto)
            assert first.mciState.state == pb.EgmMCIState.MCI_STOPPED and first.motorState.state == 1
            second = await asyncio.to_thread(_receive, sensor)
            assert second.header.seqno == 1 and 0 < second.header.tm - first.header.tm <= 8  # 4 ms, stamped as read
            pos, ori = await c.ask("7 GETC", 2)  # feedback in the current tool and work object, as GETC
            getc = [float(v) for v in pos.split()[3:]]
            fb = second.feedBack.cartesian
            assert np.allclose([fb.pos.x, fb.pos.y, fb.pos.z], getc, atol=1e-3)
            assert [round(v, 6) for v in (fb.orient.u0, fb.orient.u1, fb.orient.u2, fb.orient.u3)] == \
                [float(v) for v in ori.split()[3:]]
            assert await c.ask("8 EGM 0.1 0.1 1") == ["8 ERR 110 EGM refused: a position stream runs"]
            x, y, z = getc
            assert await c.ask(f"9 POS {x + 20:.3f} {y:.3f} {z:.3f}") == ["9 OK"]
            assert await c.ask(f"10 ORI {ori.split(maxsplit=3)[3]}") == ["10 OK"]
            assert await c.ask("11 MOVEL") == ["11 ACK"]  # moves run while it streams
            assert await c.ask("12 STREAM 0") == ["12 ERR 110 STREAM refused: a motion is running"]
            assert await c.ask("13 PING") == ["13 PONG"]
            assert await c.ask("14 STATE") == ["14 OK 1 1"]
            assert await c.line() == "11 DONE"
            assert await c.ask("15 STOP") == ["15 OK 0"]  # ends the stream (no motion ran)
            assert not fake.server.streaming  # type: ignore[union-attr]
            stats = fake.egm_stream_stats
            # it streamed through the move: more than 10 ticks of its clock, sent or (a stalled thread) skipped
            assert stats is not None and stats.sent == len(stats.seqnos) and stats.sent + stats.skipped_ticks > 10, stats
            assert await c.ask("16 STREAM 0") == ["16 OK 0"]  # harmless
            assert await c.ask("17 STREAM 1") == ["17 OK 1"]
            assert fake.server.streaming  # type: ignore[union-attr]
            assert await c.ask("18 BYE") == ["18 OK"]
        await _wait_until(lambda: not fake.server.streaming)  # type: ignore[union-attr]
        assert not fake.server.streaming  # type: ignore[union-attr]  # no stream without its client
    finally:
        fake.stop_thread()
        sensor.close()
    no_egm = start_fake(time_scale=0.05)
    try:
        async with raw_client(no_egm) as c:
            assert (await c.ask("1 HELLO 1"))[0].startswith("1 OK 1 ")
            assert await c.ask("2 STREAM 1") == ["2 ERR 151 EGM stream setup failed: no UdpUc device"]
            assert await c.ask("3 STREAM 0") == ["3 OK 0"]
    finally:
        no_egm.stop_thread()



async def test_the_frame_stays_fixed_while_streaming() -> None:
    # EGMActPose fixed the feedback's frame at STREAM 1: TOOL and WOBJ wait for STREAM 0 (module and fake).
    async with fake_and_robot(egm=True, robot_kw={"egm_isolation": "thread"}) as (fake, robot):
        await robot.start_stream(timeout_s=3.0)
        for select in (robot.set_tool, robot.set_wobj):
            with pytest.raises(DeviceRejected, match="position stream runs"):
                await select("tool0" if select == robot.set_tool else "wobj0", timeout_s=2.0)
        await robot.stop_stream(timeout_s=2.0)
        await robot.set_tool("tool0", timeout_s=2.0)
    module = (Path(__file__).parents[2] / "drivers" / "abb_robot" / "rapid" / "CellctlServer.mod").read_text()
    handle = module[module.index("FUNC bool HandleLine") :]
    assert handle.index('IF cellctl_stream_on AND (verb="TOOL" OR verb="WOBJ") THEN') < handle.index("Forward id,CMD_TOOL;")


async def test_a_guidance_session_is_stamped_on_the_streams_controller_clock() -> None:
    # One controller clock: a guidance session's header.tm and feedBack.time are the uptime the position stream
    # reads (a session-relative tm made a session's last datagram, read just after a stream began, a clock step).
    sensor = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sensor.bind((LOOPBACK, 0))
    sensor.settimeout(1.0)
    fake = start_fake(egm_sensor_port=sensor.getsockname()[1], time_scale=0.2, egm_uptime_ms=123_456)
    try:
        async with raw_client(fake) as c:
            assert (await c.ask("1 HELLO 1"))[0].startswith("1 OK 1 ")
            assert await c.ask("2 EGM 0.1 0.1 1") == ["2 ACK"]
            first = await asyncio.to_thread(_receive, sensor)
            assert first.header.seqno == 0 and 123_456 <= first.header.tm < 133_456, first.header
            assert abs(first.feedBack.time.sec + 1e-6 * first.feedBack.time.usec - time.time()) < 5  # EgmClock: UNIX time
            assert (await c.ask("3 STOP"))[0] == "3 OK 1"  # a session was running
    finally:
        fake.stop_thread()
        sensor.close()
