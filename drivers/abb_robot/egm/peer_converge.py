"""Waiting for the EGM peer's reference to converge (:meth:`abb_robot.egm.peer.EgmPeer.correct_to`)."""

from __future__ import annotations

import asyncio
import math
import time
from typing import TYPE_CHECKING

from cellctl.ports import CartesianPose, DeviceDisconnected, DeviceTimeout, MotionInterrupted

if TYPE_CHECKING:
    from abb_robot.egm.peer import EgmPeer


async def wait_converged(
    peer: EgmPeer, generation: int, *, deadline: float, timeout_s: float, min_session: int = 1
) -> CartesianPose:
    """Wait until ``peer``'s reference of ``generation`` has converged in a session numbered ``min_session``
    or later; see :meth:`EgmPeer.correct_to <abb_robot.egm.peer.EgmPeer.correct_to>` for the errors."""
    started = time.monotonic()
    name = peer.settings.name
    while True:
        died = peer.died()
        if died is not None:
            raise DeviceDisconnected(name, f"{died} during the correction; the next EGM use starts it again")
        snap = peer.snapshot()
        now = time.monotonic()
        fresh = (
            snap.session >= min_session
            and snap.received_at is not None
            and snap.received_at >= started - peer.settings.receive_timeout_s
        )
        if fresh and snap.received_at is not None and now - snap.received_at > peer.settings.receive_timeout_s:
            raise MotionInterrupted(
                name, f"EGM data stopped: nothing for {now - snap.received_at:.2f} s on UDP port {peer.port}"
            )
        if fresh and snap.fault is not None:
            raise MotionInterrupted(name, f"EGM session faulted: {snap.fault}")
        if (
            fresh
            and snap.reference_generation == generation
            and snap.converged_cycles >= peer.settings.settle_cycles
            and snap.feedback is not None
        ):
            return snap.feedback
        if fresh and snap.ended:
            raise MotionInterrupted(name, f"EGM session ended ({snap.mci}) before the pose converged")
        if not fresh and now - started > peer.settings.receive_timeout_s:
            raise DeviceTimeout(
                name,
                f"no EGM data on UDP port {peer.port} within {peer.settings.receive_timeout_s:g} s: check the "
                "controller's UDPUC remote address and port, the PC firewall, and that RAPID runs EGM",
            )
        if now >= deadline:
            err = "" if snap.position_error_mm is None else (
                f"; last error {snap.position_error_mm:.3f} mm, {math.degrees(snap.rotation_error_rad or 0.0):.3f} deg"
            )
            raise DeviceTimeout(name, f"pose did not converge within {timeout_s:g} s{err}")
        await asyncio.sleep(0.004)
