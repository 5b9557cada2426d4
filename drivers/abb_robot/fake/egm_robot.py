"""The robot side of EGM in the fake controller: a pose-mode session like ``EGMRunPose``.

While a session runs, a dedicated thread sends an ``EgmRobot`` datagram every ``period_s``
(4 ms) from its own UDP socket to the sensor's address, with seqno counting from 0, ``tm`` on the
controller's uptime clock (the position stream's, one clock as on a controller), ``feedBack.time``
and ``planned.time`` the wall clock at the same instant (UNIX s and us, as egm.proto defines
``EgmClock``), the TCP pose (current tool, work object) as feedback, the reference in use as
planned pose, and motor, MCI and RAPID states. Between two sends it drains
the ``EgmSensor`` replies and keeps the newest reference. The robot follows the reference after
a dead time, as a first-order lag limited in speed; without new replies it holds the last
reference (without repeatability noise: EGM converges on the controller's own measurement of
the robot, which is what the feedback reports). The session ends

- converged: every axis within the band for ``cond_s`` (after the first reference), or
- on a communication timeout: no reply for ``comm_timeout_s`` (ERR_UDPUC_COMM, elog 41822), not counting
  the time this thread itself ran late (it sent nothing then: a loaded host, not a silent sensor), or
- on STOP, on motors off, or on an unreachable reference.

The last datagram of a session carries MCI_STOPPED (converged, stopped) or MCI_ERROR.
Optional seeded loss drops outgoing datagrams and incoming replies at the given rates, each
datagram by what it is (seqno), not by when it comes: see :func:`loss_draw`.

The same thread and socket run the Position Stream (:mod:`abb_robot.fake.egm_stream`) between
sessions: one EGM user at a time, as the RAPID module allows.
"""

from __future__ import annotations

import enum
import json
import logging
import math
import select
import socket
import threading
import time
from collections import deque
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Callable

import numpy as np

from abb_robot import unit_quaternion
from abb_robot.egm import egm_pb2 as pb
from abb_robot.egm.peer_core import set_realtime_priority
from abb_robot.fake.egm_stream import StreamRunner, egm_clock
from abb_robot.fake.model import rot_x, rot_y, rot_z
from abb_robot.fake.robot import FakeRobot, interpolate
from cellctl.ports import CartesianPose

if TYPE_CHECKING:
    from abb_robot.fake.controller import FakeControllerConfig


log = logging.getLogger(__name__)


class EgmEnd(enum.Enum):
    """How a session ended."""

    CONVERGED = "converged"
    COMM_TIMEOUT = "comm_timeout"
    STOPPED = "stopped"
    MOTORS_OFF = "motors_off"
    UNREACHABLE = "unreachable"


@dataclass(frozen=True)
class EgmSessionParams:
    """What the EGM request asked for: convergence band per axis and the time to hold it."""

    band_mm: float
    band_deg: float
    cond_s: float


@dataclass(frozen=True)
class EgmDynamics:
    """How the fake robot follows EGM references."""

    period_s: float = 0.004
    comm_timeout_s: float = 1.0
    dead_time_s: float = 0.008
    tau_s: float = 0.015
    max_speed_mm_s: float = 250.0
    max_speed_deg_s: float = 30.0


@dataclass
class EgmSessionStats:
    """What the controller side saw during one session (for tests and the benchmark)."""

    sent: int = 0
    dropped_out: int = 0
    replies: int = 0
    dropped_in: int = 0
    bad_replies: int = 0
    missed_cycles: int = 0
    missed_while_late: int = 0  # of those, cycles where this loop itself woke late (its own stall)
    tick_overruns: int = 0
    duration_s: float = 0.0
    end: str = ""
    detail: str = ""
    rtt_ms: list[float] = field(default_factory=list)
    dropped_seqnos: list[int] = field(default_factory=list)
    missed_seqnos: list[int] = field(default_factory=list)
    reply_seqnos: list[int] = field(default_factory=list)  # of every EgmSensor read, dropped or not (-1: none)
    dropped_reply_seqnos: list[int] = field(default_factory=list)

    def summary(self) -> dict[str, object]:
        d = asdict(self)
        for name in ("dropped_seqnos", "reply_seqnos", "dropped_reply_seqnos"):
            del d[name]
        rtt = np.asarray(self.rtt_ms)
        d["rtt_ms"] = {
            "count": int(rtt.size),
            "p50": float(np.percentile(rtt, 50)) if rtt.size else None,
            "p99": float(np.percentile(rtt, 99)) if rtt.size else None,
            "max": float(rtt.max()) if rtt.size else None,
        }
        return d


OUT, IN, IN_UNNUMBERED = 0, 1, 2  # loss_draw's directions: EgmRobot, EgmSensor by seqno, EgmSensor by place


def loss_draw(seed: int, direction: int, session: int, index: int) -> float:
    """The draw in [0, 1) that drops one datagram when below the rate: ``default_rng([seed, direction,
    session, index]).random()``, session counted from 0 by this fake, index the seqno (an EgmSensor
    without one: its place among the session's replies). The host's timing cannot change it."""
    return float(np.random.default_rng([seed, direction, session, index]).random())


@dataclass(frozen=True)
class EgmOutcome:
    end: EgmEnd
    detail: str
    stats: EgmSessionStats


class EgmRobotSide:
    """Runs EGM sessions against one sensor address (the controller's UDPUC remote address).

    Args:
        robot: the shared fake robot.
        config: the controller's configuration; this side reads its ``egm_*`` fields (the sensor
            address, dynamics, loss rates and thread priority), ``seed`` and ``stats_file``.
    """

    def __init__(self, robot: FakeRobot, config: FakeControllerConfig) -> None:
        for name, p in (("loss_out", config.egm_loss_out), ("loss_in", config.egm_loss_in)):
            if not (0.0 <= p < 1.0):
                raise ValueError(f"{name} must be in [0, 1), got {p}")
        assert config.egm_sensor_port is not None
        self.robot = robot
        self.config = config
        self.sensor_address = (config.egm_sensor_host, config.egm_sensor_port)
        self._sessions = 0  # sessions run so far: the next one's number in loss_draw
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind(("0.0.0.0" if config.egm_sensor_host not in ("127.0.0.1", "localhost") else "127.0.0.1", 0))
        self._sock.setblocking(False)
        self._wake = threading.Event()
        self._stop_request = threading.Event()
        self._closed = False
        self._lock = threading.Lock()
        self._pending: tuple[EgmSessionParams, Callable[[EgmOutcome], None]] | None = None
        self._active = False
        self.last_stats: EgmSessionStats | None = None
        self.stream = StreamRunner(
            robot, config, self._sock, self.sensor_address, np.random.default_rng(config.seed), self._wake
        )
        self._thread = threading.Thread(target=self._run, name="fake-egm-robot", daemon=True)
        self._thread.start()

    @property
    def local_address(self) -> tuple[str, int]:
        return self._sock.getsockname()

    @property
    def active(self) -> bool:
        with self._lock:
            return self._active or self._pending is not None

    def start_stream(self) -> None:
        """Start (or restart, at seqno 0) the position stream in the EGM thread; refused while a session runs."""
        if self.active:
            raise RuntimeError("an EGM session is running")
        self.stream.start()

    def begin(self, params: EgmSessionParams, on_end: Callable[[EgmOutcome], None]) -> None:
        """Start a session; ``on_end`` is called from the EGM thread when it ends."""
        with self._lock:
            if self._active or self._pending is not None or self.stream.running:
                raise RuntimeError("an EGM session or a position stream is already running")
            self._stop_request.clear()
            self._pending = (params, on_end)
        self._wake.set()

    def request_stop(self) -> None:
        self._stop_request.set()

    def close(self) -> None:
        self._closed = True
        self._stop_request.set()
        self.stream.stop(timeout_s=0.0)
        self._wake.set()
        self._thread.join(timeout=2.0)
        self._sock.close()

    # -- thread -------------------------------------------------------------------------------

    def _run(self) -> None:
        if self.config.egm_rt_priority is not None:
            refused = set_realtime_priority(self.config.egm_rt_priority)
            if refused:
                log.warning("fake EGM thread: %s", refused)
        while not self._closed:
            self._wake.wait(0.2)
            self._wake.clear()
            with self._lock:
                job = self._pending
                self._pending = None
                self._active = job is not None
            self.stream.run_pending()  # in this thread, until it is stopped
            if job is None:
                continue
            params, on_end = job
            try:
                outcome = self._session(params)
            finally:
                with self._lock:
                    self._active = False
            self.last_stats = outcome.stats
            if self.config.stats_file:
                with open(self.config.stats_file, "w", encoding="utf-8") as fh:
                    json.dump(outcome.stats.summary(), fh)
            on_end(outcome)

    def _drain(self) -> list[tuple[bytes, float]]:
        out: list[tuple[bytes, float]] = []
        while True:
            try:
                data, _addr = self._sock.recvfrom(2048)
            except (BlockingIOError, InterruptedError):
                return out
            except OSError:
                return out
            out.append((data, time.perf_counter()))

    def _session(self, params: EgmSessionParams) -> EgmOutcome:
        dyn = self.config.egm
        robot = self.robot
        stats = EgmSessionStats()
        session = self._sessions
        self._sessions += 1
        seed, loss_out, loss_in = self.config.seed, self.config.egm_loss_out, self.config.egm_loss_in
        self._drain()  # stale replies of an earlier session
        t0 = time.perf_counter()
        next_tick = t0
        last_reply = t0
        seq = 0
        reference: CartesianPose | None = None  # newest TCP reference received (wobj frame)
        delayed: deque[tuple[float, CartesianPose]] = deque()
        active_ref: CartesianPose | None = None
        goal_flange = robot.flange()
        converged_since: float | None = None
        awaiting = False
        last_send = t0
        end: EgmEnd | None = None
        detail = ""
        prev_flange = robot.flange()
        joints = robot.joints()

        while True:
            now = time.perf_counter()
            loop_late = now - next_tick > dyn.period_s / 2
            if loop_late:  # this thread itself ran late: nothing went out meanwhile, so the sensor had nothing to answer
                last_reply += now - next_tick
            # -- physics: apply references whose dead time has passed, then follow them
            while delayed and delayed[0][0] <= now:
                _, active_ref = delayed.popleft()
                flange_target, refusal = robot.check(active_ref)
                if refusal is not None:
                    end, detail = EgmEnd.UNREACHABLE, f"EGM reference refused: {refusal.reason}"
                    break
                goal_flange = flange_target  # judged on the controller's own measurement: no repeatability noise
            current = robot.flange()
            if end is None:
                current = _follow(current, goal_flange, dyn)
                robot.set_flange(current)
            tcp = robot.flange_to_tcp(current)

            # -- supervision
            converged = False
            if reference is not None:
                converged = _within_band(tcp, reference, params.band_mm, params.band_deg)
                if converged:
                    converged_since = now if converged_since is None else converged_since
                else:
                    converged_since = None
            if end is None:
                if self._stop_request.is_set() or self._closed:
                    end, detail = EgmEnd.STOPPED, "EGM session stopped"
                elif not robot.motors_on:
                    end, detail = EgmEnd.MOTORS_OFF, "motors off during the EGM session"
                elif now - last_reply > dyn.comm_timeout_s:
                    end, detail = EgmEnd.COMM_TIMEOUT, (
                        f"no data from the sensor for {dyn.comm_timeout_s:g} s (41822)"  # fits the 80-byte line
                    )
                elif converged_since is not None and now - converged_since >= params.cond_s:
                    end, detail = EgmEnd.CONVERGED, "converged"

            # -- send one EgmRobot
            if awaiting:
                stats.missed_cycles += 1
                stats.missed_seqnos.append(seq - 1)
                if loop_late:
                    stats.missed_while_late += 1
            if end is None:
                mci = pb.EgmMCIState.MCI_RUNNING
            elif end in (EgmEnd.CONVERGED, EgmEnd.STOPPED):
                mci = pb.EgmMCIState.MCI_STOPPED
            else:
                mci = pb.EgmMCIState.MCI_ERROR
            speed = float(np.linalg.norm(np.subtract(current.position_mm, prev_flange.position_mm))) / dyn.period_s
            prev_flange = current
            try:
                joints = robot.model.joints(current)
            except ValueError:
                pass  # noise put the pose a hair past a limit: report the last joints
            clock, t_now = self.stream.clock, time.monotonic()  # one controller clock for sessions and streams
            msg = _robot_message(
                seq, clock.ms(t_now) / 1000.0, clock.epoch_s(t_now), tcp, joints,
                active_ref or tcp, robot.motors_on, mci, converged, min(100.0, 100.0 * speed / dyn.max_speed_mm_s),
            )
            data = msg.SerializeToString()
            if loss_out > 0 and loss_draw(seed, OUT, session, seq) < loss_out:
                stats.dropped_out += 1
                stats.dropped_seqnos.append(seq)
                awaiting = False
            else:
                try:
                    self._sock.sendto(data, self.sensor_address)
                    awaiting = True
                except OSError:
                    awaiting = False  # ICMP unreachable and the like: the sensor is not there
            stats.sent += 1
            last_send = time.perf_counter()
            seq = (seq + 1) & 0xFFFFFFFF
            if end is not None:
                break

            # -- until the next tick: collect replies
            next_tick += dyn.period_s
            late = time.perf_counter() - next_tick
            if late > dyn.period_s / 2:
                stats.tick_overruns += 1
                last_reply += late  # the same: a stall of the fake is not the sensor's silence
                next_tick = time.perf_counter() + dyn.period_s / 2
            while True:
                remaining = next_tick - time.perf_counter()
                if remaining <= 0:
                    break
                try:
                    ready, _, _ = select.select([self._sock], [], [], remaining)
                except (OSError, ValueError):
                    break
                if not ready:
                    break
                for raw, t_rx in self._drain():
                    msg = _sensor_message(raw)
                    numbered = msg is not None and msg.header.HasField("seqno")
                    reply_seq = msg.header.seqno if numbered else -1  # type: ignore[union-attr]
                    stats.reply_seqnos.append(reply_seq)
                    way, index = (IN, reply_seq) if numbered else (IN_UNNUMBERED, len(stats.reply_seqnos) - 1)
                    if loss_in > 0 and loss_draw(seed, way, session, index) < loss_in:
                        stats.dropped_in += 1
                        stats.dropped_reply_seqnos.append(reply_seq)
                        continue
                    ref = None if msg is None else _sensor_reference(msg)
                    if ref is None:
                        stats.bad_replies += 1
                        continue
                    stats.replies += 1
                    last_reply = t_rx
                    if awaiting:
                        stats.rtt_ms.append((t_rx - last_send) * 1000.0)
                        awaiting = False
                    if reference is None or ref != reference:
                        reference = ref
                        delayed.append((t_rx + dyn.dead_time_s, ref))

        robot.settle_egm()
        stats.duration_s = time.perf_counter() - t0
        stats.end = end.value
        stats.detail = detail
        return EgmOutcome(end, detail, stats)


def _follow(current: CartesianPose, goal: CartesianPose, dyn: EgmDynamics) -> CartesianPose:
    """One period of a first-order lag toward ``goal``, limited in linear and angular speed."""
    alpha = 1.0 - math.exp(-dyn.period_s / dyn.tau_s)
    dp = np.subtract(goal.position_mm, current.position_mm)
    dist = float(np.linalg.norm(dp))
    ang = unit_quaternion.angle_between(current.quaternion_wxyz, goal.quaternion_wxyz)
    s = alpha
    max_step = dyn.max_speed_mm_s * dyn.period_s
    if dist * s > max_step:
        s = max_step / dist
    max_rot = math.radians(dyn.max_speed_deg_s) * dyn.period_s
    if ang * s > max_rot:
        s = min(s, max_rot / ang)
    return interpolate(current, goal, s)


def _within_band(actual: CartesianPose, reference: CartesianPose, band_mm: float, band_deg: float) -> bool:
    """Every axis (x, y, z in mm; rx, ry, rz in deg) of the deviation within its band."""
    d = np.subtract(actual.position_mm, reference.position_mm)
    if np.any(np.abs(d) > band_mm):
        return False
    R = reference.to_matrix()[:3, :3].T @ actual.to_matrix()[:3, :3]
    return all(abs(a) <= band_deg for a in _euler_zyx_deg(R))


def _euler_zyx_deg(R: np.ndarray) -> tuple[float, float, float]:
    """ABB's Euler angles (EulerZYX: rx, ry, rz in degrees) of a rotation, R = Rz Ry Rx."""
    ry = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    rx = math.atan2(R[2, 1], R[2, 2])
    rz = math.atan2(R[1, 0], R[0, 0])
    return (math.degrees(rx), math.degrees(ry), math.degrees(rz))


def _robot_message(
    seq: int, t_s: float, wall_s: float, tcp: CartesianPose, joints_rad: tuple[float, ...], planned: CartesianPose,
    motors_on: bool, mci: int, converged: bool, utilization: float,
) -> pb.EgmRobot:
    """One session datagram: ``t_s`` the uptime (s) for ``tm``, ``wall_s`` the wall clock (UNIX s) for ``EgmClock``."""
    msg = pb.EgmRobot()
    msg.header.seqno = seq
    msg.header.tm = int(t_s * 1000.0) & 0xFFFFFFFF
    msg.header.mtype = pb.EgmHeader.MSGTYPE_DATA
    _fill_pose(msg.feedBack.cartesian, tcp)
    msg.feedBack.joints.joints.extend(math.degrees(j) for j in joints_rad)
    msg.feedBack.time.sec, msg.feedBack.time.usec = egm_clock(wall_s)
    _fill_pose(msg.planned.cartesian, planned)
    msg.planned.time.sec, msg.planned.time.usec = egm_clock(wall_s)
    msg.motorState.state = pb.EgmMotorState.MOTORS_ON if motors_on else pb.EgmMotorState.MOTORS_OFF
    msg.mciState.state = mci
    msg.mciConvergenceMet = converged
    msg.rapidExecState.state = pb.EgmRapidCtrlExecState.RAPID_RUNNING
    msg.utilizationRate = utilization
    return msg


def _fill_pose(target: pb.EgmPose, pose: CartesianPose) -> None:
    target.pos.x, target.pos.y, target.pos.z = pose.position_mm
    q = pose.quaternion_wxyz
    target.orient.u0, target.orient.u1, target.orient.u2, target.orient.u3 = q


def _sensor_message(raw: bytes) -> pb.EgmSensor | None:
    """An EgmSensor datagram parsed; None if it is garbage."""
    msg = pb.EgmSensor()
    try:
        msg.ParseFromString(raw)
    except Exception:  # noqa: BLE001 - protobuf raises DecodeError and friends; any of them means garbage
        return None
    return msg


def _sensor_reference(msg: pb.EgmSensor) -> CartesianPose | None:
    """The pose reference in an EgmSensor; None if it is not a usable one."""
    if msg.header.mtype != pb.EgmHeader.MSGTYPE_CORRECTION or not msg.planned.HasField("cartesian"):
        return None
    cart = msg.planned.cartesian
    if not cart.HasField("pos"):
        return None
    pos = (cart.pos.x, cart.pos.y, cart.pos.z)
    try:
        if cart.HasField("euler"):  # ABB's EulerZYX in degrees: R = Rz(z) Ry(y) Rx(x)
            rx, ry, rz = (math.radians(v) for v in (cart.euler.x, cart.euler.y, cart.euler.z))
            T = np.eye(4)
            T[:3, :3] = rot_z(rz) @ rot_y(ry) @ rot_x(rx)
            T[:3, 3] = pos
            return CartesianPose.from_matrix(T)
        if cart.HasField("orient"):
            q = (cart.orient.u0, cart.orient.u1, cart.orient.u2, cart.orient.u3)
            return CartesianPose(pos, unit_quaternion.normalise(q))
    except ValueError:
        return None
    return None
