"""The robot's position feedback over EGM's Position Stream: :class:`EgmStream` implements
:class:`cellctl.ports.PoseStream` for :class:`abb_robot.AbbRobot`.

``STREAM 1`` has the controller send an ``EgmRobot`` every 4 ms (feedback: the TCP in the current
tool and work object, as GETC reports it; ``header.tm``: ms on the controller's uptime-like clock)
while RAPID moves run; the sensor-side :class:`~abb_robot.egm.peer.EgmPeer` keeps every datagram
with its host receive time; ``STREAM 0`` ends it.

Timestamps: ``tm`` is put on the host's clock by the lower envelope of (receive time - tm) over
the stream: the least-delayed datagram bounds the transport delay, so a sample's instant is
``tm + min(receive - tm)``. The receive jitter is gone; the least transport delay stays in, a
constant the cell's laser-to-robot latency estimate absorbs. The instant is then put on the clock
the driver was given (its offset from ``time.monotonic``, measured when the stream starts; the
clock must run at the host's rate). Without ``tm`` the stream uses ``feedBack.time`` (same clock,
s), without either the receive times.

The one offset holds only while the controller's clock runs on without a step. Each datagram is
checked against it (:class:`ClockGuard`): its stamp must come after the previous one's, and its
(receive - stamp) must not fall below the envelope by more than :data:`STEP_TOL_S` plus the jitter
the stream showed. A step (the controller's clock set, its EGM restarted with other stamps) breaks
the stream: :meth:`EgmStream.latest` gives None from then on (a supervising caller stops the robot)
and :meth:`EgmStream.stop` raises :class:`~cellctl.ports.DeviceProtocolError` naming it.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from abb_robot import protocol as P
from abb_robot.egm.peer import EgmPeer
from abb_robot.egm.peer_core import F_FB_TIME, F_GEN, F_POS, F_QUAT, F_RX, F_SEQNO, F_SRC, F_TM, STREAM_WIDTH
from abb_robot.link import RapidLink, deadline_in
from cellctl.ports import (
    CartesianPose,
    DeviceDisconnected,
    DeviceProtocolError,
    DeviceRejected,
    DeviceTimeout,
    PoseSample,
)

MAX_SAMPLES = 262_144
"""A stream keeps its newest samples, at most this many (about 17 min at 4 ms)."""
STOP_POLL_S = 0.004
"""After the stream ended (STREAM 0, a STOP), the peer is looked at this often until no more datagrams come (s)."""
STOP_POLLS = 12  # ... at most this many times
QUIET_POLLS = 3  # ... until this many looks in a row found none (the datagrams on their way arrive with some jitter)
BUSY_TAG = f"{int(P.ErrorCode.BUSY)} BUSY"
_CTL = STREAM_WIDTH  # the record's stamp on the controller's clock (s since the stream's first sample)
_U32 = float(1 << 32)
STEP_TOL_S = 0.005
"""How far (s) a datagram's (receive - stamp) may fall below the stream's envelope, beyond the jitter the
stream showed while its envelope settled, before it counts as a forward step of the controller's clock.
Measured with the fake on a loaded 2-core host (3-4 busy processes besides, both EGM isolations): once
settled, the envelope never fell by more than 2 ms; only the first few datagrams, delayed together,
lower it by more (up to 26 ms), which the settling takes in."""
SETTLE_SAMPLES = 10
SETTLE_S = 0.040
"""The envelope counts as settled once this many datagrams within ``STEP_TOL_S`` of it have come over at
least this long (s, controller clock) without it falling by more; a step before that is taken in
unnoticed (the stream's first 40 ms or so: the robot has not started its moves yet)."""


@dataclass(frozen=True)
class PoseStreamStats:
    """What a position stream delivered (the running one, or the last one stopped).

    Attributes:
        received: datagrams collected (duplicates and stale ones are the peer's, see ``EgmPeer.stats``).
        lost: datagrams missing: seqno gaps between those received (losses before the first and after
            the last one received cannot be seen).
        gap_events: gaps of one or more datagrams.
        overwritten: datagrams the peer's ring dropped before they were read.
        other_sender: datagrams dropped because they came from a sender the peer was locked onto before
            the controller took the lock (a stray one: not this robot's poses).
        stamp: what timed the samples: "tm", "feedBack.time" or "receive".
        offset_s: host ``time.monotonic`` minus controller time at the stream's first sample (s):
            the lower envelope of (receive - tm).
        delay_p50_s, delay_max_s: receive time minus mapped instant (s): the receive jitter the mapping removed.
        max_interval_s: longest time between two samples received (s, controller clock).
        clock_offset_s: the driver's clock minus ``time.monotonic`` (s).
        clock_break: why the stream was refused (the controller's clock stepped), "" if it was not.
    """

    received: int
    lost: int
    gap_events: int
    overwritten: int
    other_sender: int
    stamp: str
    offset_s: float
    delay_p50_s: float
    delay_max_s: float
    max_interval_s: float
    clock_offset_s: float
    clock_break: str = ""


@dataclass(frozen=True)
class PoseStreamRecords:
    """Every sample of a stream as received, in time order (for inspection and tests).

    Attributes:
        seqno: the header's sequence numbers.
        tm_ms: ``header.tm`` as sent (ms, the controller's clock, wraps at 2**32; NaN if absent).
        feedback_time_s: ``feedBack.time`` (s, the controller's clock; NaN if absent).
        received_s: host receive times (``time.monotonic``, s).
        t_s: the samples' instants on the driver's clock (s), as :class:`PoseSample` has them.
        position_mm, quaternion_wxyz: the feedback poses (TCP in the current tool and work object).
    """

    seqno: np.ndarray
    tm_ms: np.ndarray
    feedback_time_s: np.ndarray
    received_s: np.ndarray
    t_s: np.ndarray
    position_mm: np.ndarray
    quaternion_wxyz: np.ndarray


class ClockGuard:
    """Checks that a stream's stamps keep to one offset from their receive times (see the module docstring)."""

    def __init__(self) -> None:
        self.floor = math.inf  # the envelope: the least (receive - stamp) so far (s)
        self.last = -math.inf  # the previous datagram's stamp (s, controller clock)
        self.jitter = math.nan  # median (receive - stamp) above the envelope while it settled (s; NaN: settling)
        self._settling: list[float] = []  # (receive - stamp) of the datagrams near the envelope since it last fell
        self._settle_from = math.nan

    def check(self, ctl: np.ndarray, rx: np.ndarray, seq: np.ndarray) -> str | None:
        """Take a chunk's stamps (s, controller clock) and receive times, in receive order; why they break the stream."""
        back = np.flatnonzero(np.diff(np.concatenate([[self.last], ctl])) <= 0)
        if back.size:
            i = int(back[0])
            went = 1e3 * ((self.last if i == 0 else ctl[i - 1]) - ctl[i])
            return _clock_break(f"went back: header.tm of seqno {int(seq[i])} is {went:.0f} ms before the previous one's")
        self.last = float(ctl[-1])
        d = rx - ctl
        k = 0
        while math.isnan(self.jitter) and k < len(d):
            self._settle(float(d[k]), float(ctl[k]))
            k += 1
        if k == len(d):
            return None
        tol = STEP_TOL_S + self.jitter
        before = np.minimum.accumulate(np.concatenate([[self.floor], d[k:]]))[:-1]
        fell = np.flatnonzero(d[k:] < before - tol)
        if fell.size:
            i = int(fell[0])
            ahead = 1e3 * (before[i] - d[k + i])
            return _clock_break(f"stepped forward: from seqno {int(seq[k + i])} on, header.tm runs at least {ahead:.0f} ms "
                                f"ahead of the stream's receive times (tolerance {1e3 * tol:.1f} ms)")
        self.floor = min(self.floor, float(d[k:].min()))
        return None

    def _settle(self, d: float, t: float) -> None:
        """One datagram while the envelope settles: a fall of more than the tolerance starts it anew."""
        if d < self.floor - STEP_TOL_S:  # those before came late together (a stall of the host): not a step
            self._settling, self._settle_from = [], t
        self.floor = min(self.floor, d)
        if d <= self.floor + STEP_TOL_S:
            self._settling.append(d)
        if len(self._settling) >= SETTLE_SAMPLES and t - self._settle_from >= SETTLE_S:
            self.jitter = float(np.median(np.asarray(self._settling) - self.floor))


def _clock_break(what: str) -> str:
    return (f"the controller's EGM clock {what}: the poses cannot be put on the cell's clock, so the position "
            "stream is refused. Start the stream again; if it recurs, look for what steps the controller's clock "
            "(its time being set, EGM restarted mid-stream)")


class EgmStream:
    """The position stream on one controller. See the module docstring.

    Args:
        link: the link the ``STREAM`` requests go over.
        peer: the sensor-side peer (None: EGM is not configured, every call is refused).
        clock: the clock the samples' instants are given on (s; the cell's, ``time.monotonic`` on hardware).
        guidance_active: whether an EGM guidance session runs (a stream is refused meanwhile).
    """

    def __init__(
        self, link: RapidLink, peer: EgmPeer | None, *, clock: Callable[[], float], guidance_active: Callable[[], bool]
    ) -> None:
        self.link = link
        self.peer = peer
        self.name = link.name
        self.clock = clock
        self._guidance_active = guidance_active
        self._gen: int | None = None  # the peer's generation of the running stream (None: none runs)
        self._since = 0
        self._chunks: list[np.ndarray] = []
        self._count = 0
        self._overwritten = 0
        self._other = 0  # records dropped as another sender's (the lock moved on to the controller)
        self._src = math.nan  # the sender of the records held (IPv4 as an integer)
        self._stamp = ""
        self._stamp0 = math.nan
        self._offset = math.inf
        self._clock_offset = 0.0
        self._last: np.ndarray | None = None
        self._latest: PoseSample | None = None  # built from _last when asked (latest() is polled every few ms)
        self._ended = False  # the controller ended the stream (a STOP); its samples wait for stop()
        self._acked_at = self._ended_at = math.nan  # when STREAM 1 was acknowledged, when a STOP ended it (monotonic s)
        self._foreign0 = 0  # the peer's count of datagrams refused from other senders, at STREAM 1
        self._guard = ClockGuard()
        self._broken = ""  # why the stream was refused (its clock stepped); latest() is None, stop() raises

    @property
    def active(self) -> bool:
        """A stream runs on the controller as far as the driver knows (started, not stopped, not ended by a STOP)."""
        return self._gen is not None and not self._ended

    # -- the port -------------------------------------------------------------------------------

    async def start(self, *, timeout_s: float) -> None:
        """Start the stream (``STREAM 1``); the previous collection is dropped. The peer starts on demand."""
        if self.peer is None:
            raise DeviceRejected(
                self.name, "the position stream needs EGM: set egm_port in the robot's settings (the controller's "
                "UDPUC remote port)",
            )
        if self._guidance_active():
            raise DeviceRejected(
                self.name, "position stream refused: an EGM guidance session (fine correction) runs; start the "
                "stream when it has ended", BUSY_TAG,
            )
        peer = self.peer
        deadline = deadline_in(timeout_s)
        await self.link.ensure_connected(deadline)
        await peer.start(timeout_s=max(deadline - time.monotonic(), 0.001))
        if self._gen is not None:  # not stopped: end it first, so no datagram of it passes for the new one
            if not self._ended:
                await self._end_on_controller(deadline)
            peer.end_stream()
        since = peer.stream_count()  # before the new generation: none of its records comes earlier
        m0 = time.monotonic()
        c = self.clock()
        self._reset(peer.begin_stream(), since, c - 0.5 * (m0 + time.monotonic()))
        try:
            self._foreign0 = peer.counter("foreign")
            await self._request(1, deadline)
            self._acked_at = time.monotonic()
        except BaseException:
            peer.end_stream()
            self._gen = None
            with contextlib.suppress(Exception):  # its answer lost: the controller may stream; stop it, best effort
                await asyncio.wait_for(self._request(0, deadline_in(1.0), reconnect=False), 1.0)
            raise

    async def stop(self, *, timeout_s: float) -> tuple[PoseSample, ...]:
        """Stop the stream (``STREAM 0``); the samples since :meth:`start`, in time order.

        A link that is down already ended the stream on the controller: the samples come all the
        same. Any other error (refused while the robot moves, no answer) is raised and the stream
        goes on, collected as before: stop it again. A stream whose controller clock stepped is
        stopped and refused: :class:`DeviceProtocolError` (its records stay for inspection). A stream
        whose EGM process died is stopped and refused: :class:`DeviceDisconnected` (the next start
        starts the process again). A stream that ran ``egm_receive_timeout_s`` or longer without a
        single datagram is stopped and refused: :class:`DeviceTimeout` (the controller sends them
        elsewhere, or the firewall drops them).
        """
        if self._gen is None or self.peer is None:
            raise DeviceRejected(self.name, "no position stream was started; call start_stream first")
        deadline = deadline_in(timeout_s)
        ended_at = self._ended_at if self._ended else time.monotonic()
        if not self._ended:  # a STOP has ended it already (and STREAM is refused while the robot decelerates)
            await self._end_on_controller(deadline)
            self.peer.end_stream()
        self._gen, self._ended = None, False
        died = self.peer.died()
        if died is not None:
            raise DeviceDisconnected(self.name, f"{died} during the position stream: its samples are incomplete, so "
                                     "the stream is refused; start it again (that starts the EGM process again)")
        if self._broken:
            raise DeviceProtocolError(self.name, self._broken)
        ran = ended_at - self._acked_at
        if self._count == 0 and ran >= self.peer.settings.receive_timeout_s:
            raise DeviceTimeout(self.name, self._nothing_came(ran))
        return self.samples()

    def _nothing_came(self, ran: float) -> str:
        """Why a stream that ran ``ran`` s got no datagram: where the controller should send them."""
        assert self.peer is not None
        port = self.peer.port
        refused = self.peer.counter("foreign") - self._foreign0
        locked = self.peer.snapshot().controller
        other = "" if refused <= 0 or locked is None else (
            f"; {refused} datagrams from other senders were refused meanwhile (the EGM peer is locked onto "
            f"{locked[0]}:{locked[1]}; the robot's host is {self.link.settings.host})")
        return (f"no EGM datagram came in the {ran:.2f} s the position stream ran, though the controller "
                f"acknowledged STREAM 1: check the controller's UDPUC device (remote address: this PC as the "
                f"controller reaches it; remote port: {port}, egm_port) and that the PC firewall lets UDP port "
                f"{port} in{other}")

    async def _end_on_controller(self, deadline: float) -> None:
        """``STREAM 0`` (a link that is down has ended it already), then collect the datagrams sent before it."""
        try:
            await self._request(0, deadline, reconnect=False)
        except DeviceDisconnected:
            pass
        await self._collect_in_flight(deadline)

    async def _collect_in_flight(self, deadline: float) -> None:
        """Collect the datagrams the controller sent before it ended the stream that are still on their way: until
        the peer has had none for QUIET_POLLS polls (bounded)."""
        quiet = 0
        for _ in range(STOP_POLLS):
            if time.monotonic() + STOP_POLL_S > deadline:
                break
            await asyncio.sleep(STOP_POLL_S)
            quiet = 0 if self._drain() else quiet + 1
            if quiet >= QUIET_POLLS:
                break
        self._drain()

    def latest(self) -> PoseSample | None:
        """The newest sample of the running stream (None before its first, and when none runs).

        Its instant uses the envelope so far, which later samples can only lower (by the jitter at most).
        None too once the controller's clock has stepped (the stream is broken: stop it).
        """
        if self._gen is None or self._ended:
            return None
        self._drain()
        if self._broken:
            return None
        if self._latest is None and self._last is not None and math.isfinite(self._last[_CTL]):
            self._latest = PoseSample(float(self._to_clock(self._last[_CTL])), _pose(self._last))
        return self._latest

    async def ended_by_controller(self) -> None:
        """The controller has ended the stream (a STOP): what came, the datagrams still on their way included, is
        kept for :meth:`stop`, which then sends nothing; the peer answers guidance again."""
        if not (self.active and self.peer is not None):
            return
        await self._collect_in_flight(time.monotonic() + STOP_POLLS * STOP_POLL_S)
        if self.active and self.peer is not None:  # not stopped meanwhile
            self.peer.end_stream()
            self._ended, self._ended_at = True, time.monotonic()

    def discard(self) -> None:
        """Forget a running stream without a request (the robot is being closed; BYE ends it)."""
        if self._gen is not None and self.peer is not None:
            self.peer.end_stream()
        self._gen, self._ended = None, False

    async def _request(self, on: int, deadline: float, *, reconnect: bool = True) -> None:
        try:
            lines = await self.link.request("STREAM", on, deadline=deadline, reconnect=reconnect)
        except DeviceRejected as exc:
            if exc.code == BUSY_TAG:
                raise DeviceRejected(
                    self.name, f"STREAM {on} refused: the robot is moving; start the position stream before the "
                    "moves and stop it after them", exc.code,
                ) from None
            raise
        if lines[-1].fields != (str(on),):
            raise DeviceRejected(self.name, f"bad STREAM answer: {' '.join(lines[-1].fields)!r} (expected {on})")

    # -- collection -----------------------------------------------------------------------------

    def _reset(self, gen: int, since: int, clock_offset: float) -> None:
        self._gen, self._since, self._ended = gen, since, False
        self._overwritten, self._other, self._clock_offset = 0, 0, clock_offset
        self._collect_anew()

    def _collect_anew(self) -> None:
        """Drop what was collected: the samples, their clock mapping and its checks."""
        self._chunks, self._count, self._last, self._latest, self._src = [], 0, None, None, math.nan
        self._stamp, self._stamp0, self._offset = "", math.nan, math.inf
        self._guard, self._broken = ClockGuard(), ""

    def _drain(self) -> int:
        """Take the peer's new records of this stream; how many came."""
        if self.peer is None or self._gen is None:
            return 0
        rows, self._since, overwritten = self.peer.stream_records(self._since)
        self._overwritten += overwritten
        rows = rows[rows[:, F_GEN] == self._gen]
        if not len(rows):
            return 0
        src = rows[:, F_SRC]
        moved = np.flatnonzero(src != src[-1])
        if moved.size or (self._count and src[-1] != self._src):
            # The peer's lock moved on (the controller took it from a stray sender): what came from the one
            # before is not this robot's pose, and its stamps are on another clock. Start from the new sender.
            start = int(moved[-1]) + 1 if moved.size else 0
            self._other += self._count + start
            rows = rows[start:]
            self._collect_anew()
        self._src = float(src[-1])
        if not self._stamp:
            first = rows[0]
            self._stamp = "tm" if math.isfinite(first[F_TM]) else (
                "feedBack.time" if math.isfinite(first[F_FB_TIME]) else "receive")
            self._stamp0 = float(first[F_TM] if self._stamp == "tm" else first[F_FB_TIME] if self._stamp != "receive"
                                 else first[F_RX])
        ctl = self._controller_seconds(rows)
        chunk = np.column_stack([rows, ctl])
        ok = np.isfinite(ctl)
        if ok.any():
            self._offset = min(self._offset, float(np.min(rows[ok, F_RX] - ctl[ok])))
            if not self._broken and self._stamp != "receive":
                self._broken = self._guard.check(ctl[ok], rows[ok, F_RX], rows[ok, F_SEQNO]) or ""
        self._chunks.append(chunk)
        self._count += len(chunk)
        self._last, self._latest = chunk[-1], None
        if self._count > MAX_SAMPLES + 4096:
            kept = np.concatenate(self._chunks)[-MAX_SAMPLES:]
            self._chunks, self._count = [kept], len(kept)
        return len(rows)

    def _controller_seconds(self, rows: np.ndarray) -> np.ndarray:
        """The records' stamps as seconds since the stream's first sample, on the controller's clock."""
        if self._stamp == "tm":  # u32 ms: across a wrap of the counter too
            return (np.mod(rows[:, F_TM] - self._stamp0 + _U32 / 2, _U32) - _U32 / 2) / 1000.0
        if self._stamp == "feedBack.time":
            return rows[:, F_FB_TIME] - self._stamp0
        return rows[:, F_RX] - self._stamp0

    def _to_clock(self, ctl_s: float | np.ndarray) -> float | np.ndarray:
        return ctl_s + self._offset + self._clock_offset

    def _rows(self) -> np.ndarray:
        """This stream's records with a stamp, in time order."""
        if not self._chunks:
            return np.zeros((0, STREAM_WIDTH + 1))
        rows = np.concatenate(self._chunks)
        rows = rows[np.isfinite(rows[:, _CTL])]
        return rows[np.argsort(rows[:, _CTL], kind="stable")]

    # -- results --------------------------------------------------------------------------------

    def samples(self) -> tuple[PoseSample, ...]:
        """The current (or last) stream's samples, in time order."""
        rows = self._rows()
        t = self._to_clock(rows[:, _CTL])
        return tuple(PoseSample(float(ti), _pose(row)) for ti, row in zip(t, rows))

    def records(self) -> PoseStreamRecords:
        """The current (or last) stream's records as received, in time order."""
        rows = self._rows()
        return PoseStreamRecords(
            seqno=rows[:, F_SEQNO].astype(np.int64), tm_ms=rows[:, F_TM].copy(), feedback_time_s=rows[:, F_FB_TIME].copy(),
            received_s=rows[:, F_RX].copy(), t_s=np.asarray(self._to_clock(rows[:, _CTL])),
            position_mm=rows[:, F_POS : F_POS + 3].copy(), quaternion_wxyz=rows[:, F_QUAT : F_QUAT + 4].copy(),
        )

    def stats(self) -> PoseStreamStats:
        """What the current (or last) stream delivered: counts, losses, the mapping."""
        rows = np.concatenate(self._chunks) if self._chunks else np.zeros((0, STREAM_WIDTH + 1))
        seq = rows[:, F_SEQNO].astype(np.int64)
        lost, gaps = 0, 0
        if len(seq):
            steps = np.mod(np.diff(seq), 1 << 32)
            missing = steps[(steps > 1) & (steps < 1 << 31)] - 1  # a step back: the controller restarted at 0
            lost, gaps = int(missing.sum()), int(missing.size)
        ok = np.isfinite(rows[:, _CTL])
        ctl = np.sort(rows[ok, _CTL])
        delay = rows[ok, F_RX] - (rows[ok, _CTL] + self._offset)
        return PoseStreamStats(
            received=len(rows), lost=lost, gap_events=gaps, overwritten=self._overwritten, other_sender=self._other,
            stamp=self._stamp,
            offset_s=self._offset if math.isfinite(self._offset) else math.nan,
            delay_p50_s=float(np.median(delay)) if delay.size else math.nan,
            delay_max_s=float(delay.max()) if delay.size else math.nan,
            max_interval_s=float(np.diff(ctl).max()) if ctl.size > 1 else math.nan,
            clock_offset_s=self._clock_offset, clock_break=self._broken,
        )


def _pose(row: np.ndarray) -> CartesianPose:
    q = row[F_QUAT : F_QUAT + 4]
    q = q / math.sqrt(float(q @ q))
    return CartesianPose((float(row[F_POS]), float(row[F_POS + 1]), float(row[F_POS + 2])),
                         (float(q[0]), float(q[1]), float(q[2]), float(q[3])))
