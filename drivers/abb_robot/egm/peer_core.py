"""The EGM peer's inner loop: datagram supervision, the reply, and the state both expose.

:class:`PeerCore` holds one peer's session state and knows nothing of threads or processes;
:func:`serve` is the receive loop around it. The same loop runs in a thread
(``isolation="thread"``) or in a child process (``isolation="process"``, the default), where
it shares no interpreter lock with the cell's own code. The state leaves the core as a flat
vector of floats (:data:`STATUS_LEN`, NaN for "none"), so that both ways of running it publish
exactly the same thing.

While the owner has a position stream on (:func:`reference_vector`'s ``stream``), the core
answers nothing (in EGM's Position Stream the sensor sends nothing back) and appends every
accepted datagram as one record of :data:`STREAM_WIDTH` floats to a :class:`StreamSink`:
the stream's generation, seqno, ``header.tm`` (ms), ``feedBack.time`` (s), the receive time
(``time.perf_counter()``, s), the feedback pose (x y z mm, qw qx qy qz) and the sender's IPv4
address (as an integer).
"""

from __future__ import annotations

import ipaddress
import math
import os
import select
import socket
import threading
import time
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass

import numpy as np

from abb_robot.egm import egm_pb2 as pb
from abb_robot.unit_quaternion import angle_between, unit

NAN = float("nan")
BURST = 3.0
"""Replies the rate cap lets through back to back (a late cycle catching up)."""

# Status vector layout.
S_SESSION, S_CTRL_IP, S_CTRL_PORT, S_SEQNO, S_LAST_RX = 0, 1, 2, 3, 4
S_FB = 5  # 7 values: x y z qw qx qy qz
S_NJ = 12
S_JOINTS = 13  # 6 values, radians
S_MOTORS, S_MCI, S_RAPID, S_CONV_MET = 19, 20, 21, 22
S_GENERATION, S_CONVERGED, S_POS_ERR, S_ROT_ERR = 23, 24, 25, 26
S_HAS_REF = 27
S_REF = 28  # 7 values
S_STATS = 35  # the counters below, in this order
STAT_NAMES = (
    "received", "replied", "sessions", "lost", "gap_events", "duplicates", "stale", "superseded",
    "foreign", "bad", "rate_limited", "max_interarrival_s", "latency_samples",
)
S_STREAM_COUNT = S_STATS + len(STAT_NAMES)  # stream records written so far (all generations)
STATUS_LEN = S_STREAM_COUNT + 1

# Reference vector layout (written by the owner of the peer, read by the loop).
R_GENERATION, R_HAS_REF, R_POS, R_QUAT, R_TOL_MM, R_TOL_RAD = 0, 1, 2, 5, 9, 10
R_STREAM_GEN, R_STREAM_ON = 11, 12
REF_LEN = 13

# Stream record layout (one accepted datagram while a stream is on).
F_GEN, F_SEQNO, F_TM, F_FB_TIME, F_RX, F_POS, F_QUAT, F_SRC = 0, 1, 2, 3, 4, 5, 8, 12
STREAM_WIDTH = 13
STREAM_RING = 1 << 16
"""Records the stream ring holds (262 s at 4 ms); the owner drains it whenever it looks."""


def reference_vector(
    generation: int, pose: tuple[Sequence[float], Sequence[float]] | None, tol_mm: float, tol_rad: float,
    stream: tuple[int, bool] = (0, False),
) -> list[float]:
    """The reference vector the loop reads: a pose and its tolerances, or None to hold the start pose;
    ``stream``: the position stream's generation and whether it is on (collect, do not answer)."""
    v = [float(generation), 0.0, NAN, NAN, NAN, NAN, NAN, NAN, NAN, tol_mm, tol_rad,
         float(stream[0]), 1.0 if stream[1] else 0.0]
    if pose is not None:
        v[R_HAS_REF] = 1.0
        v[R_POS : R_POS + 3] = [float(c) for c in pose[0]]
        v[R_QUAT : R_QUAT + 4] = [float(c) for c in pose[1]]
    return v


class LatencySink:
    """Where reply latencies go (a bounded list here; a shared-memory ring in the child)."""

    def __init__(self, capacity: int = 1 << 17) -> None:
        self.values = np.zeros(capacity)
        self.count = 0

    def append(self, value: float) -> None:
        self.values[self.count % self.values.size] = value
        self.count += 1

    def samples(self) -> np.ndarray:
        n = min(self.count, self.values.size)
        return self.values[:n].copy()


class StreamSink:
    """Where stream records go: a ring of :data:`STREAM_WIDTH`-float rows and the count written so far
    (a numpy ring here; a shared-memory ring in the child)."""

    def __init__(self, capacity: int = STREAM_RING) -> None:
        self.rows = np.zeros((capacity, STREAM_WIDTH))
        self.count = 0

    def append(self, row: Sequence[float]) -> None:
        self.rows[self.count % self.rows.shape[0]] = row
        self.count += 1


class PeerCore:
    """One EGM sensor peer's state: lock-on, sequence supervision, convergence, the reply."""

    def __init__(
        self,
        *,
        controller_host: str | None,
        receive_timeout_s: float,
        latency: LatencySink,
        stream: StreamSink | None = None,
        preferred: Sequence[str] = (),
    ) -> None:
        self.controller_host = controller_host
        self.preferred = frozenset(preferred)  # the configured controller's IPs: accepted over any other sender
        self.preferred_heard = False  # a datagram came from them: from then on only they are accepted
        self.receive_timeout_s = receive_timeout_s
        self.latency = latency
        self.stream = stream if stream is not None else StreamSink(1)
        self.stream_gen = 0
        self.streaming = False
        self.restart = False  # the next datagram starts a new session (a new stream was asked for)
        self.t0 = time.perf_counter()
        self.out = pb.EgmSensor()
        self.stats = dict.fromkeys(STAT_NAMES, 0.0)
        self.controller: tuple[str, int] | None = None
        self.src = 0.0  # the controller's IPv4 address as an integer (stream records carry it)
        self.session = 0
        self.last_seq: int | None = None
        self.last_tm: int | None = None  # header.tm of the newest accepted datagram (ms, u32)
        self.first: tuple[int | None, bytes] | None = None  # the session's seqno-0 datagram: (header.tm, bytes)
        self.last_rx: float | None = None
        self.feedback: tuple[tuple[float, float, float], tuple[float, float, float, float]] | None = None
        self.joints: tuple[float, ...] = ()
        self.hold: tuple[tuple[float, float, float], tuple[float, float, float, float]] | None = None
        self.motors = self.mci = self.rapid = 0
        self.convergence_met = False
        self.reference: tuple[tuple[float, float, float], tuple[float, float, float, float]] | None = None
        self.generation = 0
        self.tol_mm = self.tol_rad = 0.0
        self.converged_cycles = 0
        self.pos_err: float | None = None
        self.rot_err: float | None = None
        self.reply_seq = 0

    # -- reference ----------------------------------------------------------------------------

    def apply_reference(self, v: Sequence[float]) -> None:
        """Take a reference vector (see :func:`reference_vector`): a new stream generation, a new reference."""
        stream_gen = int(v[R_STREAM_GEN])
        if stream_gen != self.stream_gen:
            self.stream_gen = stream_gen
            self.restart = True  # the controller starts the stream at seqno 0: a new session
        self.streaming = v[R_STREAM_ON] > 0.5
        generation = int(v[R_GENERATION])
        if generation == self.generation:
            return
        self.generation = generation
        self.converged_cycles = 0
        if v[R_HAS_REF] > 0.5:
            self.reference = (
                (v[R_POS], v[R_POS + 1], v[R_POS + 2]),
                (v[R_QUAT], v[R_QUAT + 1], v[R_QUAT + 2], v[R_QUAT + 3]),
            )
            self.tol_mm, self.tol_rad = v[R_TOL_MM], v[R_TOL_RAD]
        else:
            self.reference = None

    # -- datagrams ----------------------------------------------------------------------------

    def accept(self, data: bytes, addr: tuple[str, int], t_rx: float) -> bool:
        """Parse and supervise one datagram; True if it is accepted as the newest of the session."""
        st = self.stats
        silent = self.last_rx is None or t_rx - self.last_rx > self.receive_timeout_s
        if self.controller_host is not None and addr[0] != self.controller_host:
            st["foreign"] += 1
            return False
        if self.controller is not None and addr != self.controller and not self._may_take_over(addr, silent):
            st["foreign"] += 1
            return False
        msg = pb.EgmRobot()  # a new one per datagram: a reused upb message grows its arena with every parse
        try:
            msg.ParseFromString(data)
        except Exception:  # noqa: BLE001 - protobuf's DecodeError family: the datagram is garbage
            st["bad"] += 1
            return False
        if not msg.header.HasField("seqno") or not msg.feedBack.HasField("cartesian"):
            st["bad"] += 1
            return False
        cart = msg.feedBack.cartesian
        o = cart.orient
        q = unit(o.u0, o.u1, o.u2, o.u3)
        pos = (cart.pos.x, cart.pos.y, cart.pos.z)
        if q is None or not all(math.isfinite(c) for c in pos):
            st["bad"] += 1
            return False
        seq = msg.header.seqno
        tm = msg.header.tm if msg.header.HasField("tm") else None
        new_session = self.controller is None or silent or addr != self.controller or self.restart
        if not new_session and seq == 0:
            if self.first is not None and (data == self.first[1] or (tm is not None and tm == self.first[0])):
                st["duplicates"] += 1  # a copy of the session's first datagram (UDP may deliver one twice, or late)
                return False
            new_session = self._clock_went_on(tm)  # seqno 0 stamped after the last: the controller restarted EGM
        self.restart = False
        if not new_session and self.last_seq is not None:
            diff = (seq - self.last_seq) & 0xFFFFFFFF
            if diff == 0:
                st["duplicates"] += 1
                return False
            if diff > 0x7FFFFFFF:
                st["stale"] += 1
                return False
            if diff > 1:
                st["lost"] += diff - 1
                st["gap_events"] += 1
        st["received"] += 1
        if self.last_rx is not None and not new_session:
            st["max_interarrival_s"] = max(st["max_interarrival_s"], t_rx - self.last_rx)
        if new_session:
            st["sessions"] += 1
            self.session += 1
            self.controller = addr
            self.src = float(int.from_bytes(socket.inet_aton(addr[0]), "big"))
            self.first = (tm, data) if seq == 0 else None
            self.hold = (pos, q)
            self.reply_seq = 0
            self.converged_cycles = 0
        if addr[0] in self.preferred:
            self.preferred_heard = True
        self.last_seq, self.last_tm = seq, tm
        self.last_rx = t_rx
        self.feedback = (pos, q)
        self.joints = tuple(math.radians(j) for j in msg.feedBack.joints.joints)
        self.motors = msg.motorState.state if msg.HasField("motorState") else 0
        self.mci = msg.mciState.state if msg.HasField("mciState") else 0
        self.rapid = msg.rapidExecState.state if msg.HasField("rapidExecState") else 0
        self.convergence_met = bool(msg.mciConvergenceMet)
        if self.streaming:
            h, fb = msg.header, msg.feedBack
            self.stream.append((
                self.stream_gen, seq, h.tm if h.HasField("tm") else NAN,
                fb.time.sec + 1e-6 * fb.time.usec if fb.HasField("time") else NAN, t_rx, *pos, *q, self.src,
            ))
        ref = self.reference
        if ref is not None:
            dp = math.dist(pos, ref[0])
            dq = angle_between(q, ref[1])
            self.pos_err, self.rot_err = dp, dq
            self.converged_cycles = self.converged_cycles + 1 if dp <= self.tol_mm and dq <= self.tol_rad else 0
        else:
            self.pos_err = self.rot_err = None
        return True

    def _may_take_over(self, addr: tuple[str, int], silent: bool) -> bool:
        """Whether ``addr`` may take the lock from the sender it is on (``silent``: that one sent nothing for
        ``receive_timeout_s``). The configured controller's address always may (from another address, or from
        another port of its own once fresh); another sender only while the controller has not been heard, after
        that silence (a stray sender or NAT: the lock is never kept by one gone quiet), or on a new stream from
        the same IP (a new sender port)."""
        assert self.controller is not None
        if addr[0] in self.preferred:
            return self.controller[0] not in self.preferred or silent or self.restart
        if self.preferred_heard:
            return False
        return silent or (self.restart and addr[0] == self.controller[0])

    def _clock_went_on(self, tm: int | None) -> bool:
        """Whether a seqno-0 datagram stamped ``tm`` (ms, u32) comes after the newest accepted one: then the
        controller began a new session; one stamped at or before it is an old datagram come late. Without
        stamps to compare, a seqno 0 that is no copy of the session's first begins a new session."""
        if tm is None or self.last_tm is None:
            return True
        return 0 < (tm - self.last_tm) & 0xFFFFFFFF <= 0x7FFFFFFF

    def reply_bytes(self, t_rx: float) -> bytes | None:
        """The EgmSensor for this cycle: the reference, or the session's start pose."""
        ref = self.reference if self.reference is not None else self.hold
        if ref is None:
            return None
        out = self.out
        out.header.seqno = self.reply_seq
        out.header.tm = int((t_rx - self.t0) * 1000.0) & 0xFFFFFFFF
        out.header.mtype = pb.EgmHeader.MSGTYPE_CORRECTION
        cart = out.planned.cartesian
        cart.pos.x, cart.pos.y, cart.pos.z = ref[0]
        o = cart.orient
        o.u0, o.u1, o.u2, o.u3 = ref[1]
        self.reply_seq = (self.reply_seq + 1) & 0xFFFFFFFF
        return out.SerializeToString()

    # -- export -------------------------------------------------------------------------------

    def export(self, v: np.ndarray) -> None:
        """Write the state into a status vector of :data:`STATUS_LEN` floats."""
        v[:] = NAN
        v[S_SESSION] = self.session
        if self.controller is not None:
            v[S_CTRL_IP] = int(ipaddress.IPv4Address(self.controller[0]))
            v[S_CTRL_PORT] = self.controller[1]
        if self.last_seq is not None:
            v[S_SEQNO] = self.last_seq
        if self.last_rx is not None:
            v[S_LAST_RX] = self.last_rx
        if self.feedback is not None:
            v[S_FB : S_FB + 3] = self.feedback[0]
            v[S_FB + 3 : S_FB + 7] = self.feedback[1]
        n = min(6, len(self.joints))
        v[S_NJ] = n
        v[S_JOINTS : S_JOINTS + n] = self.joints[:n]
        v[S_MOTORS], v[S_MCI], v[S_RAPID] = self.motors, self.mci, self.rapid
        v[S_CONV_MET] = 1.0 if self.convergence_met else 0.0
        v[S_GENERATION] = self.generation
        v[S_CONVERGED] = self.converged_cycles
        if self.pos_err is not None and self.rot_err is not None:
            v[S_POS_ERR], v[S_ROT_ERR] = self.pos_err, self.rot_err
        v[S_HAS_REF] = 0.0 if self.reference is None else 1.0
        if self.reference is not None:
            v[S_REF : S_REF + 3] = self.reference[0]
            v[S_REF + 3 : S_REF + 7] = self.reference[1]
        for i, name in enumerate(STAT_NAMES):
            v[S_STATS + i] = self.stats[name]
        v[S_STATS + STAT_NAMES.index("latency_samples")] = self.latency.count
        v[S_STREAM_COUNT] = self.stream.count


@dataclass
class Hooks:
    """What differs between the thread and the process way of running :func:`serve`."""

    lock: AbstractContextManager[object]
    keep_going: Callable[[], bool]
    wake_fds: list[object]
    before_batch: Callable[[], None] | None = None
    after_batch: Callable[[], None] | None = None


def serve(sock: socket.socket, core: PeerCore, max_rate_hz: float, hooks: Hooks) -> None:
    """The receive loop: wait, drain to the newest datagram, supervise, reply once.

    Returns when ``hooks.keep_going()`` is False or one of ``hooks.wake_fds`` becomes readable.
    """
    tokens = BURST
    last_token_t = time.perf_counter()
    watched = [sock, *hooks.wake_fds]
    while hooks.keep_going():
        try:
            ready, _, _ = select.select(watched, [], [], 0.05)
        except (OSError, ValueError):
            return
        if not ready:
            continue
        if any(r is not sock for r in ready):
            return
        t_rx = time.perf_counter()
        newest: tuple[str, int] | None = None
        accepted = 0
        read = 0
        payload = None
        with hooks.lock:
            if hooks.before_batch is not None:
                hooks.before_batch()
            while True:
                try:
                    data, addr = sock.recvfrom(4096)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:
                    break
                read += 1
                # Each datagram's own receive time, taken once it is read: never before it came (a
                # datagram that came while this batch was being drained is not stamped with its start).
                if core.accept(data, addr, time.perf_counter()):
                    accepted += 1
                    newest = addr
            if accepted and not core.streaming:  # in a Position Stream the sensor answers nothing
                if accepted > 1:
                    core.stats["superseded"] += accepted - 1
                tokens = min(BURST, tokens + (t_rx - last_token_t) * max_rate_hz)
                last_token_t = t_rx
                if tokens < 1.0:
                    core.stats["rate_limited"] += 1
                else:
                    tokens -= 1.0
                    payload = core.reply_bytes(t_rx)
        if payload is not None and newest is not None:
            t_tx = time.perf_counter()  # taken before the send: a loopback send may switch to the receiver
            try:
                sock.sendto(payload, newest)
                with hooks.lock:
                    core.stats["replied"] += 1
                    core.latency.append(t_tx - t_rx)
            except OSError:
                pass
        if read and hooks.after_batch is not None:
            hooks.after_batch()


def empty_status() -> np.ndarray:
    """The status vector of a peer that has received nothing yet."""
    v = np.zeros(STATUS_LEN)
    PeerCore(controller_host=None, receive_timeout_s=1.0, latency=LatencySink(1)).export(v)
    return v


def sample_robot_message() -> pb.EgmRobot:
    """A well-formed EgmRobot (seqno 0, TCP at (1, 2, 3) mm, unit orientation, MCI running) to exercise a core."""
    msg = pb.EgmRobot()
    msg.header.seqno = 0
    c = msg.feedBack.cartesian
    c.pos.x, c.pos.y, c.pos.z = 1.0, 2.0, 3.0
    c.orient.u0, c.orient.u1, c.orient.u2, c.orient.u3 = 1.0, 0.0, 0.0, 0.0
    msg.feedBack.joints.joints.extend([0.0] * 6)
    msg.mciState.state = pb.EgmMCIState.MCI_RUNNING
    return msg


def warm_up() -> None:
    """Run every code path of the loop once on a throwaway core (first calls are slow)."""
    msg = sample_robot_message()
    core = PeerCore(controller_host=None, receive_timeout_s=1.0, latency=LatencySink(4), stream=StreamSink(4))
    core.apply_reference(reference_vector(1, ((1.0, 2.0, 3.0), (1.0, 0.0, 0.0, 0.0)), 0.1, 0.01))
    data = msg.SerializeToString()
    for seq in (0, 1):
        msg.header.seqno = seq
        core.accept(msg.SerializeToString() if seq else data, ("127.0.0.1", 1), time.perf_counter())
    core.accept(data, ("127.0.0.1", 1), time.perf_counter())  # a copy of the session's first
    core.reply_bytes(time.perf_counter())
    core.apply_reference(reference_vector(1, None, 0.0, 0.0, stream=(1, True)))
    msg.header.tm = 8
    msg.feedBack.time.sec, msg.feedBack.time.usec = 1, 8000
    for seq in (0, 1):
        msg.header.seqno = seq
        core.accept(msg.SerializeToString(), ("127.0.0.1", 1), time.perf_counter())
    core.export(np.zeros(STATUS_LEN))
    core.latency.append(0.0)


def set_realtime_priority(priority: int) -> str | None:
    """Ask SCHED_FIFO at ``priority`` for the calling thread; the reason if refused, else None."""
    if not hasattr(os, "sched_setscheduler"):
        return "real-time scheduling is not available on this platform"
    try:
        os.sched_setscheduler(threading.get_native_id(), os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, ValueError) as exc:
        return f"could not get real-time priority {priority}: {exc}"
    return None


def no_lock() -> AbstractContextManager[object]:
    return nullcontext()
