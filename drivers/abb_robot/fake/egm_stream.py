"""The robot side of EGM's Position Stream in the fake controller (``EGMStreamStart`` / ``EGMStreamStop``).

While a stream runs, the EGM thread sends an ``EgmRobot`` every ``period_s`` (4 ms) to the sensor's
address and reads nothing back: seqno from 0, ``header.tm`` on the controller's uptime-like clock
(ms, wrapping at 2**32; not UNIX time), ``feedBack.time`` and ``planned.time`` (``EgmClock``) the
wall clock at the instant ``tm`` names (s and us since 1 Jan 1970, as egm.proto defines it: the
host's ``time.time``), the TCP pose in the current tool and work object as feedback and planned
pose (taken from :meth:`FakeRobot.tcp`, so a running RAPID move shows), motor, MCI (stopped: no
guidance runs) and RAPID states. The samples lie on the controller's 4 ms grid of whole
milliseconds; each is stamped with the whole millisecond nearest to the instant its pose was
read, which is the grid's when the thread wakes on time (a sample read late skips the grid ticks
it overran, so no ``tm`` comes twice). Instants are ``time.monotonic``, the fake robot's clock.

Faults for tests: a seeded share of the datagrams dropped (``egm_loss_out``), each datagram
leaving up to ``egm_stream_jitter_s`` after its sample (seeded, uniform), and
:meth:`StreamControl.cut`, after which nothing more is sent while the RAPID side still believes
the stream runs (the network or the controller's EGM died).
"""

from __future__ import annotations

import math
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from abb_robot.egm import egm_pb2 as pb
from abb_robot.fake.robot import FakeRobot

if TYPE_CHECKING:
    from abb_robot.fake.controller import FakeControllerConfig


SAMPLE_WINDOW_S = 0.0002
"""How closely a sample's pose and its instant go together (s)."""


class UptimeClock:
    """The controller's clocks as functions of ``time.monotonic``: the uptime ``tm`` (u32 ms) and the wall
    clock of ``EgmClock`` (UNIX s, the host's ``time.time``).

    Args:
        start_ms: the clock's reading (ms) at construction.
    """

    def __init__(self, start_ms: int) -> None:
        self.boot = time.monotonic() - start_ms / 1000.0

    def ms(self, t: float) -> float:
        """The clock at monotonic time ``t`` (ms, unwrapped)."""
        return (t - self.boot) * 1000.0

    def at_ms(self, ms: float) -> float:
        """The monotonic time (s) at which the clock reads ``ms``."""
        return self.boot + ms / 1000.0

    def epoch_s(self, t: float) -> float:
        """The wall clock at monotonic time ``t`` (UNIX s): ``time.time()`` read now, carried back to ``t``."""
        for _ in range(3):  # a thread switch between the reads is retried (the offset within 0.2 ms)
            m0 = time.monotonic()
            wall = time.time()
            m1 = time.monotonic()
            if m1 - m0 < SAMPLE_WINDOW_S:
                break
        return wall + t - 0.5 * (m0 + m1)


def egm_clock(wall_s: float) -> tuple[int, int]:
    """``EgmClock`` (sec, usec) of a UNIX time (s), to the nearest microsecond."""
    sec, usec = divmod(round(wall_s * 1e6), 1_000_000)
    return sec, usec


@dataclass
class EgmStreamStats:
    """What the controller did in one stream (live while it runs; for tests).

    ``sampled_at`` (``time.monotonic``, s) and ``tm`` are per datagram the controller produced, sent or
    not, in seqno order (``seqnos``); ``sent_at`` per datagram that left.
    """

    sent: int = 0
    dropped_out: int = 0
    cut_out: int = 0
    skipped_ticks: int = 0
    seqnos: list[int] = field(default_factory=list)
    tm: list[int] = field(default_factory=list)
    sampled_at: list[float] = field(default_factory=list)
    sent_at: list[float] = field(default_factory=list)
    dropped_seqnos: list[int] = field(default_factory=list)
    cut_at: float | None = None
    duration_s: float = 0.0


class StreamControl:
    """Starting, stopping and cutting one stream across threads (the line server's and the EGM thread)."""

    def __init__(self) -> None:
        self.stop = threading.Event()
        self.done = threading.Event()
        self.cut_flag = threading.Event()
        self.stats = EgmStreamStats()

    def cut(self) -> None:
        """From now on nothing is sent; the stream goes on as far as RAPID knows."""
        self.cut_flag.set()


class StreamRunner:
    """The position stream of one fake controller: started and stopped from the line server's thread,
    run in the EGM thread (:meth:`run_pending`) on the EGM socket.

    Args:
        robot: the shared fake robot (its TCP is the feedback).
        config: the controller's configuration (``egm`` period, loss, jitter, uptime, seed).
        sock, address: the EGM socket and the sensor's address.
        rng: the seeded loss and jitter generator.
        wake: set to wake the EGM thread.
    """

    def __init__(
        self, robot: FakeRobot, config: FakeControllerConfig, sock: socket.socket, address: tuple[str, int],
        rng: np.random.Generator, wake: threading.Event,
    ) -> None:
        if not (math.isfinite(config.egm_stream_jitter_s) and 0.0 <= config.egm_stream_jitter_s < 1.0):
            raise ValueError(f"egm_stream_jitter_s must be in [0, 1) s, got {config.egm_stream_jitter_s}")
        start_ms = config.egm_uptime_ms
        if start_ms is None:
            start_ms = int(np.random.default_rng([config.seed, 7]).integers(0, 1 << 32))
        self.clock = UptimeClock(start_ms)
        self._args = (sock, address, robot, config, self.clock, rng)
        self._wake = wake
        self._lock = threading.Lock()
        self._pending: StreamControl | None = None
        self._current: StreamControl | None = None

    @property
    def running(self) -> bool:
        """A stream was started and has not stopped."""
        with self._lock:
            return self._current is not None and not self._current.done.is_set()

    @property
    def stats(self) -> EgmStreamStats | None:
        """The running or last stream's statistics (None: none yet)."""
        with self._lock:
            return None if self._current is None else self._current.stats

    def start(self) -> None:
        """Start (or restart, at seqno 0) the stream."""
        self.stop()
        with self._lock:
            self._current = self._pending = StreamControl()
        self._wake.set()

    def stop(self, timeout_s: float = 2.0) -> bool:
        """Stop the stream and wait (up to ``timeout_s``) until it has sent its last datagram; True if one ran."""
        with self._lock:
            control = self._current
        if control is None or control.done.is_set():
            return False
        control.stop.set()
        control.done.wait(timeout_s)
        return True

    def cut(self) -> None:
        """The network or the controller's EGM dies: the running stream sends nothing more, RAPID does not know."""
        with self._lock:
            if self._current is not None:
                self._current.cut()

    def run_pending(self) -> None:
        """Run a stream started since the last call until it is stopped (in the EGM thread)."""
        with self._lock:
            control, self._pending = self._pending, None
        if control is None:
            return
        try:
            run_stream(*self._args, control)
        finally:
            control.done.set()


def run_stream(
    sock: socket.socket, address: tuple[str, int], robot: FakeRobot, config: FakeControllerConfig, clock: UptimeClock,
    rng: np.random.Generator, control: StreamControl,
) -> EgmStreamStats:
    """Send the stream until ``control.stop`` is set (called in the EGM thread)."""
    period_ms = config.egm.period_s * 1000.0
    stats = control.stats
    t_start = time.monotonic()
    next_ms = math.ceil(clock.ms(t_start)) + 1  # the grid: whole ms, every period (the first a ms away at least)
    seq = 0
    joints: tuple[float, ...] = ()
    while not control.stop.is_set():
        wait = clock.at_ms(next_ms) - time.monotonic()
        if wait > 0 and control.stop.wait(wait):
            break
        for _ in range(3):  # the pose's instant within 0.2 ms: a thread switch between clock and pose is retried
            t0 = time.monotonic()
            tcp = robot.tcp()
            t1 = time.monotonic()
            if t1 - t0 < SAMPLE_WINDOW_S:
                break
        t = 0.5 * (t0 + t1)
        try:
            joints = robot.joints()
        except ValueError:
            pass  # a pose a hair past a limit: report the last joints
        ms = round(clock.ms(t))
        msg = pb.EgmRobot()  # a new one each time: a cleared upb message keeps what it held in its arena
        wall_s = clock.epoch_s(clock.at_ms(ms))  # the instant tm names, on the wall clock
        _fill(msg, seq, ms, wall_s, tcp.position_mm, tcp.quaternion_wxyz, joints, robot.motors_on)
        stats.seqnos.append(seq)
        stats.tm.append(ms & 0xFFFFFFFF)
        stats.sampled_at.append(t)
        if control.cut_flag.is_set():
            stats.cut_out += 1
            if stats.cut_at is None:
                stats.cut_at = t
        elif config.egm_loss_out > 0 and rng.random() < config.egm_loss_out:
            stats.dropped_out += 1
            stats.dropped_seqnos.append(seq)
        else:
            data = msg.SerializeToString()
            if config.egm_stream_jitter_s > 0:
                time.sleep(max(0.0, t + rng.uniform(0.0, config.egm_stream_jitter_s) - time.monotonic()))
            try:
                sock.sendto(data, address)
                stats.sent += 1
                stats.sent_at.append(time.monotonic())
            except OSError:
                pass  # ICMP unreachable and the like: the sensor is not there
        seq = (seq + 1) & 0xFFFFFFFF
        next_ms += period_ms
        behind = max(ms + 0.5, clock.ms(time.monotonic())) - next_ms
        if behind > 0:  # the thread stalled: the ticks it missed are not sent late, no stamp comes twice
            missed = math.ceil(behind / period_ms)
            stats.skipped_ticks += missed
            next_ms += missed * period_ms
    stats.duration_s = time.monotonic() - t_start
    return stats


def _fill(
    msg: pb.EgmRobot, seq: int, ms: int, wall_s: float, pos: tuple[float, float, float],
    q: tuple[float, float, float, float], joints_rad: tuple[float, ...], motors_on: bool,
) -> None:
    """One stream datagram: ``ms`` the uptime stamp (ms), ``wall_s`` the wall clock at that instant (UNIX s)."""
    msg.header.seqno = seq
    msg.header.tm = ms & 0xFFFFFFFF
    msg.header.mtype = pb.EgmHeader.MSGTYPE_DATA
    sec, usec = egm_clock(wall_s)
    for part in (msg.feedBack, msg.planned):  # the fake's servo has no lag: planned = measured
        c = part.cartesian
        c.pos.x, c.pos.y, c.pos.z = pos
        c.orient.u0, c.orient.u1, c.orient.u2, c.orient.u3 = q
        part.joints.joints.extend(math.degrees(j) for j in joints_rad)
        part.time.sec, part.time.usec = sec, usec
    msg.motorState.state = pb.EgmMotorState.MOTORS_ON if motors_on else pb.EgmMotorState.MOTORS_OFF
    msg.mciState.state = pb.EgmMCIState.MCI_STOPPED
    msg.rapidExecState.state = pb.EgmRapidCtrlExecState.RAPID_RUNNING
