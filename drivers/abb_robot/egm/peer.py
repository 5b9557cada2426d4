"""The sensor side of EGM: a UDP peer that answers the controller with the newest pose reference.

The controller is the UDP client: once per EGM cycle (4 ms) it sends ``EgmRobot`` to the port
configured in its UDPUC device ("Remote Port Number"). :class:`EgmPeer` binds that port, locks
onto one sender's address (datagrams from any other address are counted and ignored: the
controller's address, ``preferred_host``, once heard; else the first sender's until it is silent
for ``receive_timeout_s``), and answers each received cycle with one ``EgmSensor`` holding the
newest reference, so it replies at the controller's rate, capped at ``max_rate_hz`` (250 Hz) by
a token bucket that lets a late cycle catch up but never lets the average exceed the cap.

The receive loop (:mod:`abb_robot.egm.peer_core`) runs in a child process of its own by default
(``isolation="process"``: no interpreter lock shared with the cell's code, state in shared
memory, see :mod:`abb_robot.egm.peer_process`) or in a thread (``isolation="thread"``). It drains
the socket to the newest datagram each time it wakes (older ones are counted as superseded,
never answered late) and supervises:

- sequence numbers: gaps (lost datagrams), duplicates (a copy of the session's seqno 0 too), and
  datagrams older than the last one (stale, discarded); seqno 0 stamped after the last datagram,
  a new sender, silence or a new stream start a new session;
- silence: no datagram for ``receive_timeout_s`` ends the session as far as the peer knows;
- motor, RAPID and MCI state: motors off, RAPID stopped and MCI_ERROR are faults, MCI_STOPPED
  ends the session (RAPID_UNDEFINED is accepted: controllers report it after a restart);
- convergence: consecutive cycles with the feedback pose within the tolerance of the reference.

Before a reference is set, the peer answers with the pose the robot had when the session began,
so the robot holds still. Poses are TCP poses in the frame the RAPID side gave to EGMActPose
(cellctl's module uses the current tool and work object, as for MoveL).

For EGM's Position Stream (the controller sends, the sensor answers nothing) the owner turns
collecting on with :meth:`EgmPeer.begin_stream`: the loop then replies to nothing and keeps every
accepted datagram as a record (seqno, ``header.tm``, ``feedBack.time``, receive time, pose) in a
ring (shared memory with process isolation), which :meth:`EgmPeer.stream_records` drains.

:meth:`EgmPeer.correct_to` implements :class:`cellctl.ports.FineCorrection` on its own, for a
controller whose RAPID program runs the EGM session; :class:`abb_robot.AbbRobot` uses the peer
together with its RAPID link, which starts the session itself.

The peer's settings and what it reports (:class:`EgmPeerSettings`, :class:`EgmPeerStats`,
:class:`EgmSnapshot`) live in :mod:`abb_robot.egm.peer_types`; they are importable from here too.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import logging
import math
import socket
import subprocess
import threading
import time
from collections import deque
from multiprocessing.shared_memory import SharedMemory

import numpy as np

from abb_robot import unit_quaternion
from abb_robot.egm.peer_core import (
    F_RX,
    R_HAS_REF,
    R_POS,
    R_QUAT,
    R_STREAM_GEN,
    R_STREAM_ON,
    REF_LEN,
    S_STATS,
    S_STREAM_COUNT,
    STAT_NAMES,
    STATUS_LEN,
    STREAM_WIDTH,
    Hooks,
    LatencySink,
    PeerCore,
    StreamSink,
    empty_status,
    reference_vector,
    serve,
    set_realtime_priority,
    warm_up,
)
from abb_robot.egm.peer_converge import wait_converged
from abb_robot.egm.peer_process import (
    REF_AT,
    RING,
    RING_AT,
    STATUS_AT,
    TOTAL,
    SeqBlock,
    command,
    stream_rows,
)
from abb_robot.egm.peer_start import exit_reason, resolve_ipv4
from abb_robot.egm.peer_types import (
    EgmPeerSettings,
    EgmPeerStats,
    EgmSnapshot,
    latency_percentiles_ms,
    snapshot_from_status,
)
from cellctl.ports import CartesianPose, DeviceDisconnected, DeviceTimeout

__all__ = [
    "EgmPeer",
    "EgmPeerSettings",
    "EgmPeerStats",
    "EgmSnapshot",
    "check_tolerances",
    "latency_percentiles_ms",
    "snapshot_from_status",
]

log = logging.getLogger(__name__)


def check_tolerances(tolerance_mm: float, tolerance_rad: float) -> None:
    """ValueError unless both convergence tolerances are finite and > 0."""
    if not (tolerance_mm > 0 and math.isfinite(tolerance_mm)):
        raise ValueError(f"tolerance_mm must be > 0, got {tolerance_mm}")
    if not (tolerance_rad > 0 and math.isfinite(tolerance_rad)):
        raise ValueError(f"tolerance_rad must be > 0, got {tolerance_rad}")


class EgmPeer:
    """Sensor-side EGM peer; implements :class:`cellctl.ports.FineCorrection`.

    Use ``await peer.start()`` (binds the port, starts the loop) and ``await peer.close()``.
    With ``isolation="process"`` (the default) the loop runs in a child process, so the cell's
    own Python work never holds it up; ``"thread"`` keeps it in this process.
    """

    def __init__(self, settings: EgmPeerSettings = EgmPeerSettings()) -> None:
        self.settings = settings
        self._running = False
        self._port: int | None = None
        self._generation = 0
        self._stream_gen = 0
        self._stream_on = False
        self._reference_vec = reference_vector(0, None, 0.0, 0.0)
        self._core_status = empty_status()
        # thread isolation
        self._lock = threading.Lock()
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._core: PeerCore | None = None
        # process isolation
        self._process: subprocess.Popen[bytes] | None = None
        self._shm: SharedMemory | None = None
        self._ref_block: SeqBlock | None = None
        self._status_block: SeqBlock | None = None
        self._ring: np.ndarray | None = None
        self._stream_rows: np.ndarray | None = None

    # -- lifecycle ----------------------------------------------------------------------------

    @property
    def port(self) -> int:
        """The bound UDP port (useful when the settings asked for port 0)."""
        if self._port is None:
            raise RuntimeError("EGM peer not started")
        return self._port

    @property
    def running(self) -> bool:
        """Started, not closed, and the loop (its child process, its thread) still alive."""
        return self._running and self.died() is None

    def died(self) -> str | None:
        """Why the loop is gone though the peer was started and not closed (None: it runs, or was never started)."""
        if not self._running:
            return None
        process, thread = self._process, self._thread
        if process is not None and process.poll() is not None:
            return f"the EGM process (pid {process.pid}) died ({exit_reason(process.returncode)})"
        if thread is not None and not thread.is_alive():
            return "the EGM receive thread ended"
        return None

    async def start(self, *, timeout_s: float = 30.0) -> None:
        """Bind the UDP port and start the receive loop. Safe to call twice; a loop that died is started
        again (on the port bound before), and the log says so.

        With process isolation the child interpreter needs about half a second to start;
        ``timeout_s`` bounds that (DeviceTimeout when it does not report in time).
        """
        deadline = time.monotonic() + timeout_s
        if self._running:
            died = self.died()
            if died is None:
                return
            log.warning("%s: %s; starting it again on UDP port %s", self.settings.name, died, self._port)
            await self._release()
        self._running = True
        try:
            preferred, why = await resolve_ipv4(self.settings.preferred_host, min(2.0, timeout_s / 2))
            if why is not None:
                log.warning("%s: %s: EGM is taken from the first sender (the lock passes on after %g s of silence)",
                            self.settings.name, why, self.settings.receive_timeout_s)
            if self.settings.isolation == "thread":
                self._start_thread(preferred)
            else:
                await self._start_process(max(deadline - time.monotonic(), 0.001), preferred)
        except BaseException:
            self._running = False
            raise

    def _bind_error(self, detail: str) -> DeviceDisconnected:
        return DeviceDisconnected(self.settings.name, f"{detail}; is another EGM peer running on that port?")

    def _start_thread(self, preferred: tuple[str, ...]) -> None:
        s = self.settings
        port = s.port if self._port is None else self._port
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind((s.bind_host, port))
        except OSError as exc:
            sock.close()
            raise self._bind_error(f"cannot bind UDP {s.bind_host}:{port} ({exc.strerror})") from exc
        sock.setblocking(False)
        self._sock = sock
        self._port = int(sock.getsockname()[1])
        self._core = PeerCore(controller_host=s.controller_host, receive_timeout_s=s.receive_timeout_s,
                              latency=LatencySink(), stream=StreamSink(), preferred=preferred)
        self._core.apply_reference(self._reference_vec)
        self._thread = threading.Thread(target=self._thread_main, name=f"egm-peer-{self._port}", daemon=True)
        self._thread.start()

    def _thread_main(self) -> None:
        assert self._sock is not None and self._core is not None
        warm_up()
        if self.settings.rt_priority is not None:
            refused = set_realtime_priority(self.settings.rt_priority)
            if refused:
                log.warning("%s: %s", self.settings.name, refused)
        serve(self._sock, self._core, self.settings.max_rate_hz,
              Hooks(lock=self._lock, keep_going=lambda: self._running, wake_fds=[]))

    async def _start_process(self, timeout_s: float, preferred: tuple[str, ...]) -> None:
        s = self.settings
        shm = SharedMemory(create=True, size=TOTAL * 8)
        array = np.ndarray((TOTAL,), dtype=np.float64, buffer=shm.buf)
        array[:] = 0.0
        self._shm = shm
        self._ref_block = SeqBlock(array, REF_AT, REF_LEN)
        self._status_block = SeqBlock(array, STATUS_AT, STATUS_LEN)
        self._ring = array[RING_AT : RING_AT + RING]
        self._stream_rows = stream_rows(array)
        self._status_block.write(empty_status())  # "nothing yet" until the child publishes
        self._ref_block.write(self._reference_vec)
        port = s.port if self._port is None else self._port
        process = subprocess.Popen(command(s, shm.name, port=port, preferred=preferred), stdin=subprocess.PIPE,
                                   stdout=subprocess.PIPE)
        self._process = process
        assert process.stdout is not None
        loop = asyncio.get_running_loop()
        try:
            line = await asyncio.wait_for(loop.run_in_executor(None, process.stdout.readline), timeout_s)
            reply = json.loads(line) if line else {"error": "the EGM process ended before it started"}
        except asyncio.TimeoutError:
            await self._stop_process()
            raise DeviceTimeout(s.name, f"the EGM process did not start within {timeout_s:g} s") from None
        except ValueError:
            reply = {"error": "the EGM process answered garbage when starting"}
        if "port" not in reply:
            await self._stop_process()
            raise self._bind_error(str(reply.get("error")))
        self._port = int(reply["port"])
        if reply.get("warning"):
            log.warning("%s: %s", s.name, reply["warning"])

    async def close(self) -> None:
        """Stop the loop and release the port. Safe to call twice."""
        if not self._running:
            return
        await self._release()

    async def _release(self) -> None:
        self._running = False
        if self.settings.isolation == "thread":
            thread = self._thread
            if thread is not None:
                await asyncio.get_running_loop().run_in_executor(None, thread.join, 2.0)
            if self._sock is not None:
                self._sock.close()
        else:
            await self._stop_process()

    async def _stop_process(self) -> None:
        process = self._process
        if process is not None:
            if process.stdin is not None:
                try:
                    process.stdin.write(b"stop\n")
                    process.stdin.close()
                except (OSError, ValueError):
                    pass
            loop = asyncio.get_running_loop()
            try:
                await asyncio.wait_for(loop.run_in_executor(None, process.wait), 3.0)
            except asyncio.TimeoutError:
                process.kill()
                await loop.run_in_executor(None, process.wait)
            if process.stdout is not None:
                process.stdout.close()
        self._read_status_block()  # the last status and latencies stay readable after the process is gone
        if self._ring is not None:
            self._ring = self._ring.copy()
        if self._stream_rows is not None:
            self._stream_rows = self._stream_rows.copy()
        self._ref_block = self._status_block = None
        if self._shm is not None:
            try:
                self._shm.close()
            except BufferError:
                pass
            self._shm.unlink()
            self._shm = None
        self._process = None

    # -- references ---------------------------------------------------------------------------

    def set_reference(self, target: CartesianPose, *, tolerance_mm: float, tolerance_rad: float) -> int:
        """Send ``target`` from the next cycle on; convergence is judged with these tolerances.

        Returns the reference generation, which :class:`EgmSnapshot` echoes once the loop uses it.
        """
        check_tolerances(tolerance_mm, tolerance_rad)
        pose = (tuple(map(float, target.position_mm)), unit_quaternion.normalise(target.quaternion_wxyz))
        self._generation += 1
        self._publish_reference(reference_vector(self._generation, pose, tolerance_mm, tolerance_rad))
        return self._generation

    def clear_reference(self) -> None:
        """Go back to holding the pose the session started at."""
        self._generation += 1
        self._publish_reference(reference_vector(self._generation, None, 0.0, 0.0))

    def _publish_reference(self, vec: list[float]) -> None:
        vec[R_STREAM_GEN], vec[R_STREAM_ON] = float(self._stream_gen), 1.0 if self._stream_on else 0.0
        self._reference_vec = vec
        if self.settings.isolation == "thread":
            if self._core is not None:
                with self._lock:
                    self._core.apply_reference(vec)
        elif self._ref_block is not None:
            self._ref_block.write(vec)

    # -- position stream ----------------------------------------------------------------------

    def begin_stream(self) -> int:
        """Collect a new position stream from the next datagram on (and answer none); returns its generation.

        The next datagram starts a new session (the controller starts a stream at seqno 0).
        """
        self._stream_gen += 1
        self._stream_on = True
        self._publish_reference(list(self._reference_vec))
        return self._stream_gen

    def end_stream(self) -> None:
        """Stop collecting; the loop answers datagrams again (guidance)."""
        self._stream_on = False
        self._publish_reference(list(self._reference_vec))

    @property
    def streaming(self) -> bool:
        """A position stream is being collected."""
        return self._stream_on

    def stream_count(self) -> int:
        """Stream records written so far (all streams): where a reader of the next stream starts."""
        if self.settings.isolation == "thread":
            if self._core is None:
                return 0
            with self._lock:
                return self._core.stream.count
        return int(self._status()[S_STREAM_COUNT])

    def stream_records(self, since: int) -> tuple[np.ndarray, int, int]:
        """The stream records written from absolute index ``since`` on, still in the ring.

        Returns ``(rows, count, overwritten)``: rows of :data:`~abb_robot.egm.peer_core.STREAM_WIDTH`
        floats (layout ``F_*`` in :mod:`abb_robot.egm.peer_core`; ``F_RX`` converted to
        ``time.monotonic()`` seconds), the count written so far (the next ``since``), and how many
        records after ``since`` the ring had overwritten before they were read.
        """
        if self.settings.isolation == "thread":
            if self._core is None or self._core.stream.count <= since:
                return np.zeros((0, STREAM_WIDTH)), since, 0
            with self._lock:
                count, ring = self._core.stream.count, self._core.stream.rows
                first = max(since, count - ring.shape[0])
                rows = ring[np.arange(first, count) % ring.shape[0]].copy()
        else:
            ring = self._stream_rows
            count = int(self._status()[S_STREAM_COUNT])
            if ring is None or count <= since:
                return np.zeros((0, STREAM_WIDTH)), max(since, count), 0
            cap = ring.shape[0]
            first = max(since, count - cap)
            rows = ring[np.arange(first, count) % cap].copy()
            # The child may have written on meanwhile (a batch ahead of its status): drop what it may have overwritten.
            safe_from = int(self._status()[S_STREAM_COUNT]) + 256 - cap
            if safe_from > first:
                rows = rows[safe_from - first :]
                first = min(safe_from, count)
        rows[:, F_RX] += time.monotonic() - time.perf_counter()
        return rows, count, first - since

    def _status(self) -> np.ndarray:
        if self.settings.isolation == "thread":
            if self._core is not None:
                with self._lock:
                    self._core.export(self._core_status)
            return self._core_status.copy()
        self._read_status_block()
        return self._core_status.copy()

    def _read_status_block(self) -> None:
        """Take the child's newest status from shared memory (process isolation), if it has one."""
        if self._status_block is not None:
            values = self._status_block.read()
            if values is not None:
                self._core_status = values

    def snapshot(self) -> EgmSnapshot:
        """What the peer knows now, with the reference the next cycle sends."""
        snap = snapshot_from_status(self._status())
        v = self._reference_vec  # what the next cycle sends, whether or not a cycle used it yet
        reference = None
        if v[R_HAS_REF] > 0.5:
            reference = CartesianPose(
                (v[R_POS], v[R_POS + 1], v[R_POS + 2]), unit_quaternion.normalise(v[R_QUAT : R_QUAT + 4])
            )
        return dataclasses.replace(snap, reference=reference)

    def counter(self, name: str) -> int:
        """One counter of :meth:`stats` (``"foreign"``, ``"received"``, ...), without copying the latencies."""
        return int(self._status()[S_STATS + STAT_NAMES.index(name)])

    def stats(self) -> EgmPeerStats:
        """Counters and reply latencies since the peer started."""
        v = self._status()
        counts = {name: v[S_STATS + i] for i, name in enumerate(STAT_NAMES)}
        st = EgmPeerStats(**{k: int(counts[k]) for k in (
            "received", "replied", "sessions", "lost", "gap_events", "duplicates", "stale", "superseded",
            "foreign", "bad", "rate_limited")})
        st.max_interarrival_s = float(counts["max_interarrival_s"])
        n = int(counts["latency_samples"])
        if self.settings.isolation == "thread":
            samples = self._core.latency.samples() if self._core is not None else np.zeros(0)
        else:
            ring = self._ring if self._ring is not None else np.zeros(0)
            samples = ring[: min(n, ring.size)].copy()
        st.reply_latency_s = deque(samples.tolist(), maxlen=RING)
        return st

    # -- FineCorrection -----------------------------------------------------------------------

    async def correct_to(
        self, target: CartesianPose, *, tolerance_mm: float, tolerance_rad: float, timeout_s: float
    ) -> CartesianPose:
        """Stream ``target`` until the reported pose stays within the tolerances for
        ``settle_cycles`` cycles; returns that reported pose.

        Needs an EGM session run by the controller's program. Raises DeviceTimeout when no EGM
        data arrives or the pose does not converge in ``timeout_s``, MotionInterrupted when the
        session ends or faults first, DeviceDisconnected when the receive loop dies meanwhile.
        """
        if not (timeout_s > 0 and math.isfinite(timeout_s)):
            raise ValueError(f"timeout_s must be > 0, got {timeout_s}")
        await self.start(timeout_s=timeout_s)
        generation = self.set_reference(target, tolerance_mm=tolerance_mm, tolerance_rad=tolerance_rad)
        return await self.wait_converged(generation, deadline=time.monotonic() + timeout_s, timeout_s=timeout_s)

    async def wait_converged(
        self, generation: int, *, deadline: float, timeout_s: float, min_session: int = 1
    ) -> CartesianPose:
        """Wait until the reference of ``generation`` has converged in a session numbered
        ``min_session`` or later; see :meth:`correct_to` for the errors."""
        return await wait_converged(self, generation, deadline=deadline, timeout_s=timeout_s, min_session=min_session)
