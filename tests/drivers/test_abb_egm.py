"""EGM: the sensor-side peer, fine correction through the RAPID link, loss and timeouts."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable, Iterable
import contextlib
import itertools
import math
import os
import select
from pathlib import Path
import socket
import time
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from _abb_testkit import LOOPBACK, fake_and_robot, free_udp_port, settings_for, start_fake
from abb_robot import AbbRobot, EgmPeer, EgmPeerSettings, egm_session
from abb_robot.egm import egm_pb2 as pb
from abb_robot.fake import DEFAULT_HOME, EgmDynamics, FakeController, egm_robot
from abb_robot.fake.egm_robot import EgmSessionParams
from cellctl.ports import CartesianPose, DeviceRejected, DeviceTimeout, MotionInterrupted

Q = DEFAULT_HOME.quaternion_wxyz


def _near_home(dx: float = 0.0, dy: float = 0.0, dz: float = 0.0) -> CartesianPose:
    x, y, z = DEFAULT_HOME.position_mm
    return CartesianPose((x + dx, y + dy, z + dz), Q)


@contextlib.asynccontextmanager
async def _egm_cell(**kw: dict[str, object]) -> AsyncIterator[tuple[FakeController, AbbRobot]]:
    """``fake_and_robot(egm=True)`` with the EGM process already started (a loaded machine can take
    seconds for that), so the timed calls below time only what they are about."""
    async with fake_and_robot(egm=True, **kw) as (fake, robot):  # type: ignore[arg-type]
        await robot.egm.start(timeout_s=30.0)  # type: ignore[union-attr]
        yield fake, robot


def _drops(seed: int, direction: int, seqnos: Iterable[int], rate: float) -> list[int]:
    """The seqnos the fake's documented loss rule drops in session 0 (direction 0: EgmRobot, 1: EgmSensor)."""
    return [s for s in seqnos if np.random.default_rng([seed, direction, 0, s]).random() < rate]


def _peer_processes() -> set[int]:
    """PIDs of this process's EGM peer children, as the OS lists them."""
    me, found = os.getpid(), set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            cmdline = (entry / "cmdline").read_bytes()
        except (OSError, IndexError, ValueError):
            continue  # gone meanwhile
        if ppid == me and b"abb_robot.egm._peer_child" in cmdline:
            found.add(int(entry.name))
    return found


async def test_fine_correction_converges_on_the_reported_pose() -> None:
    async with _egm_cell() as (fake, robot):
        target = _near_home(dx=3.0, dy=-2.0, dz=1.0)
        got = await robot.correct_to(target, tolerance_mm=0.1, tolerance_rad=math.radians(0.05), timeout_s=3.0)
        assert math.dist(got.position_mm, target.position_mm) <= 0.1
        assert math.dist(fake.robot.tcp().position_mm, target.position_mm) <= 0.1  # the robot is really there
        stats = fake.last_egm_stats
        assert stats is not None and stats.end == "converged" and stats.replies > 10
        peer = robot.egm.stats()  # type: ignore[union-attr]
        assert peer.sessions == 1 and peer.lost == 0 and peer.foreign == 0 and peer.bad == 0
        assert robot.egm.snapshot().reference is None  # type: ignore[union-attr]  # back to holding


async def test_five_percent_loss_each_way_is_seen_exactly_and_survived() -> None:
    async with _egm_cell(fake_kw={"egm_loss_out": 0.05, "egm_loss_in": 0.05, "seed": 11},
                         robot_kw={"egm_cond_time_s": 0.6}) as (fake, robot):
        target = _near_home(dy=4.0)
        got = await robot.correct_to(target, tolerance_mm=0.1, tolerance_rad=math.radians(0.05), timeout_s=5.0)
        assert math.dist(got.position_mm, target.position_mm) <= 0.1
        stats = fake.last_egm_stats
        assert stats is not None and stats.end == "converged" and stats.duration_s >= 0.6  # held the band 0.6 s
        # The seed alone fixes what drops, however the host timed the two directions: EgmRobot by seqno
        # (4, 45, 58, ... at seed 11), the replies the fake read by their seqno (18, 78, ...).
        n_read = len(stats.reply_seqnos)
        assert stats.reply_seqnos == list(range(n_read))  # the peer's replies, in order, none missing
        assert stats.dropped_seqnos == _drops(11, 0, range(stats.sent), 0.05) and stats.dropped_out >= 1
        assert stats.dropped_reply_seqnos == _drops(11, 1, range(n_read), 0.05) and stats.dropped_in >= 1
        assert stats.replies == n_read - stats.dropped_in and stats.bad_replies == 0
        # The driver (the code under test) saw exactly that: every datagram not dropped, each dropped one
        # before the last it received as a sequence gap, and it sent every reply the fake read.
        delivered = [s for s in range(stats.sent) if s not in set(stats.dropped_seqnos)]
        egm = robot.egm
        assert egm is not None
        await _until(lambda: egm.stats().received >= len(delivered))  # the session's last datagrams arrive
        snap, peer = egm.snapshot(), egm.stats()
        assert peer.received == len(delivered) and snap.seqno == delivered[-1] and peer.sessions == 1
        assert peer.lost == sum(1 for s in stats.dropped_seqnos if s < delivered[-1])
        assert n_read <= peer.replied


async def test_controller_comm_timeout_ends_the_session_with_code_150() -> None:
    async with _egm_cell(fake_kw={"egm": EgmDynamics(comm_timeout_s=0.3)}) as (fake, robot):
        session = await robot.start_egm_session(band_mm=0.05, band_deg=0.05, cond_s=30.0, timeout_s=2.0)
        await asyncio.sleep(0.2)
        assert not session.done()
        await robot.egm.close()  # type: ignore[union-attr]  # the sensor goes away
        with pytest.raises(MotionInterrupted, match=r"41822.*code 150 EGM_COMM"):
            await asyncio.wait_for(session, 2.0)
        stats = fake.last_egm_stats
        assert stats is not None and stats.end == "comm_timeout" and stats.replies > 10


async def test_a_correction_the_controller_ends_in_mci_error_names_the_controllers_reason(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # (Almost) every reply lost on the way: the controller hears nothing for 0.3 s and ends the session
    # (ERR_UDPUC_COMM). Its last datagram says only MCI_ERROR; its error reply to the EGM request, here 1 s after
    # that datagram (the driver's grace widened to 3 s, so that a loaded host delays neither past the other), names
    # the cause, and the correction's error says both.
    monkeypatch.setattr(egm_session, "FAULT_REPLY_GRACE_S", 3.0, raising=False)
    async with _egm_cell(fake_kw={"egm": EgmDynamics(comm_timeout_s=0.3), "egm_loss_in": 0.999}) as (fake, robot):
        server = fake.server
        assert server is not None
        reply = server._reply_quietly  # noqa: SLF001

        async def after_the_datagram(session: object, data: bytes) -> None:
            if b" ERR " in data:
                await asyncio.sleep(1.0)
            await reply(session, data)  # type: ignore[arg-type]

        monkeypatch.setattr(server, "_reply_quietly", after_the_datagram)
        with pytest.raises(MotionInterrupted, match=r"MCI_ERROR.*controller says.*41822.*code 150 EGM_COMM"):
            await robot.correct_to(_near_home(dx=1.0), tolerance_mm=0.1, tolerance_rad=0.01, timeout_s=5.0)
        stats = fake.last_egm_stats
        assert stats is not None and stats.end == "comm_timeout" and stats.dropped_in > 0


async def test_a_stall_of_the_fake_controller_itself_is_not_taken_for_a_silent_sensor(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The fake's EGM thread comes back 0.5 s late from a wait that found no reply (a loaded host), past its 0.2 s comm
    # timeout: it sent nothing meanwhile, so the sensor had nothing to answer, and the session goes on to converge.
    real_select = select.select
    waits = itertools.count()
    stalled: list[float] = []

    def late_after_a_quiet_wait(*args: Any) -> Any:
        ready = real_select(*args)
        if next(waits) >= 5 and not ready[0] and not stalled:
            stalled.append(0.5)
            time.sleep(0.5)
        return ready

    monkeypatch.setattr(egm_robot, "select", SimpleNamespace(select=late_after_a_quiet_wait))
    async with _egm_cell(fake_kw={"egm": EgmDynamics(comm_timeout_s=0.2)},
                         robot_kw={"egm_receive_timeout_s": 2.0, "egm_cond_time_s": 0.3}) as (fake, robot):  # fmt: skip
        target = _near_home(dx=2.0)
        got = await robot.correct_to(target, tolerance_mm=0.1, tolerance_rad=math.radians(0.05), timeout_s=5.0)
        assert math.dist(got.position_mm, target.position_mm) <= 0.1
        stats = fake.last_egm_stats
        assert stalled and stats is not None and stats.end == "converged", stats


async def test_no_egm_data_on_the_pc_port_times_out_and_stops_the_session() -> None:
    wrong_port = free_udp_port()
    fake = start_fake(egm_sensor_port=wrong_port, time_scale=0.05, egm=EgmDynamics(comm_timeout_s=5.0))
    robot = AbbRobot(settings_for(fake, free_udp_port(), egm_receive_timeout_s=0.3))
    try:
        await robot.connect(timeout_s=2.0)
        await robot.egm.start(timeout_s=30.0)  # type: ignore[union-attr]  # not part of what is timed
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout, match=r"no EGM data on UDP port \d+ within 0.3 s"):
            await robot.correct_to(_near_home(dx=1.0), tolerance_mm=0.1, tolerance_rad=0.01, timeout_s=3.0)
        assert time.monotonic() - t0 < 3.0  # bounded, not hung
        await asyncio.sleep(0.1)
        stats = fake.last_egm_stats
        assert stats is not None and stats.end == "stopped"
        await robot.ping(timeout_s=1.0)  # the link is fine and idle again
        assert not fake.server.busy  # type: ignore[union-attr]
    finally:
        await robot.close()
        fake.stop_thread()


async def test_correction_timeout_stops_the_session() -> None:
    slow = EgmDynamics(max_speed_mm_s=2.0, comm_timeout_s=1.0)  # 10 mm at 2 mm/s: far too slow
    async with _egm_cell(fake_kw={"egm": slow}) as (fake, robot):
        with pytest.raises(DeviceTimeout, match=r"did not converge within 0.5 s; last error \d"):
            await robot.correct_to(_near_home(dx=10.0), tolerance_mm=0.1, tolerance_rad=0.01, timeout_s=0.5)
        await asyncio.sleep(0.1)
        assert fake.last_egm_stats is not None and fake.last_egm_stats.end == "stopped"


async def test_motors_off_during_a_correction_interrupts_it() -> None:
    slow = EgmDynamics(max_speed_mm_s=5.0, comm_timeout_s=1.0)
    async with _egm_cell(fake_kw={"egm": slow}) as (fake, robot):
        task = asyncio.create_task(
            robot.correct_to(_near_home(dx=5.0), tolerance_mm=0.1, tolerance_rad=0.01, timeout_s=5.0)
        )
        await asyncio.sleep(0.3)
        fake.set_motors(False)
        with pytest.raises(MotionInterrupted, match="motors"):
            await asyncio.wait_for(task, 3.0)


async def test_large_corrections_and_missing_egm_are_refused() -> None:
    async with _egm_cell() as (fake, robot):
        with pytest.raises(DeviceRejected, match=r"exceeds egm_max_correction_mm=20.*use move\(\)") as info:
            await robot.correct_to(_near_home(dx=25.0), tolerance_mm=0.1, tolerance_rad=0.01, timeout_s=2.0)
        assert info.value.code == "LIMIT" and fake.last_egm_stats is None
    async with fake_and_robot(egm=False) as (fake, robot):
        with pytest.raises(DeviceRejected, match="set egm_port"):
            await robot.correct_to(_near_home(dx=1.0), tolerance_mm=0.1, tolerance_rad=0.01, timeout_s=2.0)


async def test_over_limit_correction_is_refused_before_the_egm_process_starts() -> None:
    async with fake_and_robot(egm=True) as (fake, robot):
        assert robot.egm is not None and robot.settings.egm_isolation == "process"
        before = _peer_processes()
        with pytest.raises(DeviceRejected, match=r"EGM correction of 25.00 mm .* exceeds egm_max_correction_mm=20"):
            await robot.correct_to(_near_home(dx=25.0), tolerance_mm=0.1, tolerance_rad=0.01, timeout_s=30.0)
        # no child interpreter was started for it (the OS lists none), nothing bound the PC's EGM port
        assert _peer_processes() == before and not robot.egm.running and fake.last_egm_stats is None
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            probe.bind((LOOPBACK, robot.settings.egm_port))  # type: ignore[arg-type]
        # a correction within the limit then starts it
        await robot.correct_to(_near_home(dx=1.0), tolerance_mm=0.1, tolerance_rad=0.01, timeout_s=30.0)
        assert robot.egm.running and len(_peer_processes() - before) == 1


async def test_standalone_peer_corrects_in_a_session_the_controller_runs() -> None:
    port = free_udp_port()
    fake = start_fake(egm_sensor_port=port)
    peer = EgmPeer(EgmPeerSettings(port=port, bind_host=LOOPBACK, receive_timeout_s=0.3))
    ended: list[object] = []
    try:
        await peer.start()
        assert fake.egm is not None
        fake.egm.begin(EgmSessionParams(band_mm=0.01, band_deg=0.01, cond_s=30.0), ended.append)
        target = _near_home(dz=-2.0)
        got = await peer.correct_to(target, tolerance_mm=0.05, tolerance_rad=0.001, timeout_s=3.0)
        assert math.dist(got.position_mm, target.position_mm) <= 0.05
        snap = peer.snapshot()
        assert snap.converged_cycles >= 5 and snap.motors == "on" and snap.mci == "running"
        assert snap.rapid == "running" and len(snap.joints_rad) == 6
        fake.egm.request_stop()
        for _ in range(100):
            if ended:
                break
            await asyncio.sleep(0.02)
        assert ended
        with pytest.raises(MotionInterrupted, match=r"session ended \(stopped\)"):  # it just ended
            await peer.correct_to(target, tolerance_mm=0.05, tolerance_rad=0.001, timeout_s=2.0)
        await asyncio.sleep(0.4)
        with pytest.raises(DeviceTimeout, match="no EGM data"):  # nobody runs a session now
            await peer.correct_to(target, tolerance_mm=0.05, tolerance_rad=0.001, timeout_s=2.0)
    finally:
        await peer.close()
        fake.stop_thread()


# ------------------------------------------------------------------------------------------------
# The peer alone, fed by a scripted controller socket


def _robot_msg(seq: int, x: float = 1000.0, mci: int = 3, motors: int = 1, rapid: int = 2) -> bytes:
    m = pb.EgmRobot()
    m.header.seqno, m.header.tm, m.header.mtype = seq, seq * 4, pb.EgmHeader.MSGTYPE_DATA
    c = m.feedBack.cartesian
    c.pos.x, c.pos.y, c.pos.z = x, 0.0, 1500.0
    c.orient.u0, c.orient.u1, c.orient.u2, c.orient.u3 = 1.0, 0.0, 0.0, 0.0
    m.mciState.state, m.motorState.state, m.rapidExecState.state = mci, motors, rapid
    return m.SerializeToString()


class _Controller:
    def __init__(self, peer_port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((LOOPBACK, 0))
        self.sock.settimeout(1.0)
        self.peer = (LOOPBACK, peer_port)

    def send(self, data: bytes) -> None:
        self.sock.sendto(data, self.peer)

    def reply(self) -> pb.EgmSensor:
        data, _ = self.sock.recvfrom(4096)
        return pb.EgmSensor.FromString(data)

    def close(self) -> None:
        self.sock.close()


async def _settle() -> None:
    await asyncio.sleep(0.03)


async def _until(condition: Callable[[], object], timeout_s: float = 5.0) -> None:
    """Wait until the peer shows what was sent (a process peer publishes its status after replying)."""
    deadline = asyncio.get_running_loop().time() + timeout_s
    while not condition() and asyncio.get_running_loop().time() < deadline:
        await asyncio.sleep(0.01)


@pytest.mark.parametrize("isolation", ["process", "thread"])
async def test_peer_locks_on_supervises_sequences_and_replies(isolation: str) -> None:
    peer = EgmPeer(EgmPeerSettings(port=0, bind_host=LOOPBACK, receive_timeout_s=0.5, isolation=isolation))  # type: ignore[arg-type]
    await peer.start()
    ctl, intruder = _Controller(peer.port), _Controller(peer.port)
    try:
        ctl.send(_robot_msg(0))
        first = await asyncio.to_thread(ctl.reply)
        assert first.header.seqno == 0 and first.header.mtype == pb.EgmHeader.MSGTYPE_CORRECTION
        assert first.planned.cartesian.pos.x == 1000.0  # holds the pose the session began at
        intruder.send(_robot_msg(1, x=5.0))  # another address: ignored
        for seq in (1, 2, 5, 5, 3, 6):  # gap of two, a duplicate, a stale one
            ctl.send(_robot_msg(seq))
            await _settle()
        await _until(lambda: peer.stats().received == 5 and peer.stats().foreign == 1)
        s = peer.stats()
        assert s.foreign == 1 and s.lost == 2 and s.gap_events == 1 and s.duplicates == 1 and s.stale == 1
        assert s.received == 5 and s.sessions == 1
        peer.set_reference(CartesianPose((1001.0, 0.0, 1500.0), (1.0, 0.0, 0.0, 0.0)), tolerance_mm=0.1,
                           tolerance_rad=0.01)
        ctl.sock.settimeout(0.2)
        while True:  # drain earlier replies
            try:
                ctl.reply()
            except socket.timeout:
                break
        ctl.sock.settimeout(1.0)
        ctl.send(_robot_msg(7))
        r = await asyncio.to_thread(ctl.reply)
        assert r.planned.cartesian.pos.x == 1001.0 and r.header.seqno >= 4
        await _until(lambda: peer.snapshot().position_error_mm == pytest.approx(1.0))
        snap = peer.snapshot()
        assert snap.position_error_mm == pytest.approx(1.0) and snap.converged_cycles == 0
        ctl.send(b"\x08\x96\x01garbage")
        await _until(lambda: peer.stats().bad == 1)
        assert peer.stats().bad == 1
        restart = pb.EgmRobot.FromString(_robot_msg(0))
        restart.header.tm = 1000  # seqno 0 stamped after the last datagram: the controller restarted EGM
        ctl.send(restart.SerializeToString())
        await _until(lambda: peer.stats().sessions == 2)
        assert peer.stats().sessions == 2
        ctl.send(_robot_msg(1, motors=2))
        await _until(lambda: peer.snapshot().fault == "motors are off")
        assert peer.snapshot().fault == "motors are off"
        ctl.send(_robot_msg(2, mci=1))
        await _until(lambda: "MCI_ERROR" in (peer.snapshot().fault or ""))
        assert "MCI_ERROR" in (peer.snapshot().fault or "")
        ctl.send(_robot_msg(3, rapid=0))  # RAPID_UNDEFINED is accepted
        await _until(lambda: peer.snapshot().fault is None)
        assert peer.snapshot().fault is None
    finally:
        ctl.close()
        intruder.close()
        await peer.close()


async def test_peer_drains_to_the_newest_datagram() -> None:
    peer = EgmPeer(EgmPeerSettings(port=0, bind_host=LOOPBACK, isolation="thread"))
    await peer.start()
    ctl = _Controller(peer.port)
    try:
        ctl.send(_robot_msg(0))
        await asyncio.to_thread(ctl.reply)
        peer._lock.acquire()  # noqa: SLF001 - hold the receive thread while a burst queues up
        try:
            for seq in (1, 2, 3, 4):
                ctl.send(_robot_msg(seq, x=1000.0 + seq))
            await asyncio.sleep(0.05)
        finally:
            peer._lock.release()  # noqa: SLF001
        await asyncio.sleep(0.05)
        s = peer.stats()
        assert s.received == 5 and s.lost == 0
        assert peer.snapshot().feedback.position_mm[0] == 1004.0  # type: ignore[union-attr]
        assert s.replied < s.received  # the burst got fewer replies than datagrams
    finally:
        ctl.close()
        await peer.close()


async def test_peer_settings_and_port_clash_are_reported() -> None:
    with pytest.raises(ValueError, match="max_rate_hz"):
        EgmPeerSettings(max_rate_hz=0)
    with pytest.raises(ValueError, match="isolation"):
        EgmPeerSettings(isolation="fiber")  # type: ignore[arg-type]
    idle = EgmPeer(EgmPeerSettings(port=0))
    assert idle.snapshot().session == 0 and idle.snapshot().feedback is None and idle.stats().received == 0
    with pytest.raises(RuntimeError, match="not started"):
        _ = idle.port
    first = EgmPeer(EgmPeerSettings(port=0, bind_host=LOOPBACK))
    await first.start()
    second = EgmPeer(EgmPeerSettings(port=first.port, bind_host=LOOPBACK))
    try:
        with pytest.raises(Exception, match="cannot bind UDP"):
            await second.start()
    finally:
        await first.close()
        await second.close()
