"""What the EGM peer is set up with and what it reports: its settings, counters and snapshots.

The peer's loop (:mod:`abb_robot.egm.peer_core`) publishes its state as a flat status vector;
:func:`snapshot_from_status` turns one into an :class:`EgmSnapshot`, the same way whether the
loop runs in a thread or in a child process.
"""

from __future__ import annotations

import ipaddress
import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from abb_robot import unit_quaternion
from abb_robot.egm.peer_core import (
    S_CONV_MET,
    S_CONVERGED,
    S_CTRL_IP,
    S_CTRL_PORT,
    S_FB,
    S_GENERATION,
    S_HAS_REF,
    S_JOINTS,
    S_LAST_RX,
    S_MCI,
    S_MOTORS,
    S_NJ,
    S_POS_ERR,
    S_RAPID,
    S_REF,
    S_ROT_ERR,
    S_SEQNO,
    S_SESSION,
)
from abb_robot.egm.peer_process import RING
from cellctl.ports import CartesianPose

_MOTORS = {0: "undefined", 1: "on", 2: "off"}
_MCI = {0: "undefined", 1: "error", 2: "stopped", 3: "running"}
_RAPID = {0: "undefined", 1: "stopped", 2: "running"}


@dataclass(frozen=True)
class EgmPeerSettings:
    """How the sensor-side peer listens and supervises.

    Attributes:
        port: UDP port to bind (the controller's UDPUC "Remote Port Number").
        bind_host: local address to bind ("0.0.0.0": every interface).
        controller_host: if set, only datagrams from this IP are accepted.
        preferred_host: the controller's address (IPv4 or a host name, resolved when the peer starts): its
            datagrams are accepted whoever the peer is locked onto, and once it has been heard no other
            sender is. Until then (unset, unresolvable, or NAT hides it) the first sender is locked onto,
            and another takes over after ``receive_timeout_s`` of silence from it.
        max_rate_hz: average reply rate cap (token bucket, bursts of up to 3 replies).
        receive_timeout_s: silence after which the session counts as ended (or never started).
        settle_cycles: consecutive converged cycles :meth:`EgmPeer.correct_to` waits for.
        rt_priority: if set, the receive loop asks for SCHED_FIFO at this priority (1..99;
            needs CAP_SYS_NICE; refused with a logged warning otherwise).
        isolation: "process" runs the loop in a child process, "thread" in this one.
        name: the device name in errors.
    """

    port: int = 6511
    bind_host: str = "0.0.0.0"
    controller_host: str | None = None
    preferred_host: str | None = None
    max_rate_hz: float = 250.0
    receive_timeout_s: float = 0.5
    settle_cycles: int = 5
    rt_priority: int | None = None
    isolation: Literal["process", "thread"] = "process"
    name: str = "robot EGM"

    def __post_init__(self) -> None:
        if not (0 <= self.port <= 65535):
            raise ValueError(f"port must be 0..65535, got {self.port}")
        if not (0 < self.max_rate_hz <= 1000):
            raise ValueError(f"max_rate_hz must be in (0, 1000], got {self.max_rate_hz}")
        if not (0 < self.receive_timeout_s <= 60):
            raise ValueError(f"receive_timeout_s must be in (0, 60], got {self.receive_timeout_s}")
        if self.settle_cycles < 1:
            raise ValueError(f"settle_cycles must be >= 1, got {self.settle_cycles}")
        if self.isolation not in ("process", "thread"):
            raise ValueError(f"isolation must be 'process' or 'thread', got {self.isolation!r}")
        if self.rt_priority is not None and not (1 <= self.rt_priority <= 99):
            raise ValueError(f"rt_priority must be 1..99 or None, got {self.rt_priority}")


@dataclass
class EgmPeerStats:
    """Counters since the peer started (read them through :meth:`EgmPeer.stats`)."""

    received: int = 0
    replied: int = 0
    sessions: int = 0
    lost: int = 0
    gap_events: int = 0
    duplicates: int = 0
    stale: int = 0
    superseded: int = 0
    foreign: int = 0
    bad: int = 0
    rate_limited: int = 0
    max_interarrival_s: float = 0.0
    reply_latency_s: deque[float] = field(default_factory=lambda: deque(maxlen=RING))
    """Receive-to-send time of the latest replies (up to 131072), seconds."""


@dataclass(frozen=True)
class EgmSnapshot:
    """What the peer knows now; a copy, safe to keep.

    Attributes:
        session: number of sessions seen so far (0: none yet).
        controller: the address the peer is locked onto.
        seqno: sequence number of the newest accepted datagram.
        received_at: ``time.monotonic()`` of the newest accepted datagram.
        feedback: the robot's pose as the controller reports it.
        joints_rad: the robot's joints as reported.
        motors, mci, rapid: "on"/"off"/"undefined", "running"/"stopped"/"error"/"undefined",
            "running"/"stopped"/"undefined".
        convergence_met: the controller's own convergence flag.
        reference: the reference sent from the next cycle on (None: the session's start pose).
        reference_generation: the generation of the reference the newest cycle was judged
            against (:meth:`EgmPeer.set_reference` returns it).
        converged_cycles: consecutive cycles with the feedback within tolerance of the reference.
        position_error_mm, rotation_error_rad: feedback against reference in the newest cycle.
        fault: why the session cannot go on (motors off, MCI error, RAPID stopped), or None.
        ended: the controller ended the session (MCI_STOPPED or MCI_ERROR).
    """

    session: int
    controller: tuple[str, int] | None
    seqno: int | None
    received_at: float | None
    feedback: CartesianPose | None
    joints_rad: tuple[float, ...]
    motors: str
    mci: str
    rapid: str
    convergence_met: bool
    reference: CartesianPose | None
    reference_generation: int
    converged_cycles: int
    position_error_mm: float | None
    rotation_error_rad: float | None
    fault: str | None
    ended: bool


def _mono(perf_t: float) -> float:
    """A perf_counter time (CLOCK_MONOTONIC, shared by processes) as time.monotonic()."""
    return time.monotonic() - (time.perf_counter() - perf_t)


def _opt(v: float) -> float | None:
    """None for NaN (the status vector's "none"), else the value."""
    return None if math.isnan(v) else float(v)


def snapshot_from_status(v: np.ndarray) -> EgmSnapshot:
    """The :class:`EgmSnapshot` of a status vector (see :mod:`abb_robot.egm.peer_core`)."""
    motors = _MOTORS.get(int(v[S_MOTORS]), "undefined")
    mci = _MCI.get(int(v[S_MCI]), "undefined")
    rapid = _RAPID.get(int(v[S_RAPID]), "undefined")
    fault = None
    if motors == "off":
        fault = "motors are off"
    elif mci == "error":
        fault = "the controller reports an EGM error (MCI_ERROR)"
    elif rapid == "stopped":
        fault = "RAPID execution is stopped"
    controller = None
    if not math.isnan(v[S_CTRL_IP]):
        controller = (str(ipaddress.IPv4Address(int(v[S_CTRL_IP]))), int(v[S_CTRL_PORT]))
    feedback = None
    if not math.isnan(v[S_FB]):
        feedback = CartesianPose(
            (float(v[S_FB]), float(v[S_FB + 1]), float(v[S_FB + 2])),
            unit_quaternion.normalise(v[S_FB + 3 : S_FB + 7]),
        )
    reference = None
    if v[S_HAS_REF] > 0.5:
        reference = CartesianPose(
            (float(v[S_REF]), float(v[S_REF + 1]), float(v[S_REF + 2])), unit_quaternion.normalise(v[S_REF + 3 : S_REF + 7])
        )
    seqno = _opt(v[S_SEQNO])
    last_rx = _opt(v[S_LAST_RX])
    return EgmSnapshot(
        session=int(v[S_SESSION]),
        controller=controller,
        seqno=None if seqno is None else int(seqno),
        received_at=None if last_rx is None else _mono(last_rx),
        feedback=feedback,
        joints_rad=tuple(float(j) for j in v[S_JOINTS : S_JOINTS + int(v[S_NJ])]),
        motors=motors,
        mci=mci,
        rapid=rapid,
        convergence_met=bool(v[S_CONV_MET] > 0.5),
        reference=reference,
        reference_generation=int(v[S_GENERATION]),
        converged_cycles=int(v[S_CONVERGED]),
        position_error_mm=_opt(v[S_POS_ERR]),
        rotation_error_rad=_opt(v[S_ROT_ERR]),
        fault=fault,
        ended=mci in ("stopped", "error"),
    )


def latency_percentiles_ms(samples: deque[float] | list[float]) -> tuple[float, float, float]:
    """p50, p99 and max of latency samples given in seconds, in milliseconds."""
    if not samples:
        return (float("nan"), float("nan"), float("nan"))
    a = np.asarray(samples, dtype=float) * 1000.0
    return (float(np.percentile(a, 50)), float(np.percentile(a, 99)), float(a.max()))
