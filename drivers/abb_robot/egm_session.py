"""EGM sessions run through the RAPID link: fine correction (:class:`cellctl.ports.FineCorrection`).

The controller runs EGM (``EGM`` request; EGMRunPose) and ends the session once the pose has
stayed within a band for a while; the sensor-side :class:`~abb_robot.egm.peer.EgmPeer` streams
the reference meanwhile and watches what comes back. :class:`EgmSession` joins the two: it
refuses corrections too large for EGM, starts the session on the link, supervises the peer's
data (none arriving, a fault, no convergence in time: the session is stopped), and checks the
reported pose once the controller says it converged. A session is refused while a position
stream (:mod:`abb_robot.egm_stream`) runs: one EGM user at a time on the controller's device.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable

from abb_robot import protocol as P
from abb_robot import unit_quaternion
from abb_robot.egm.peer import EgmPeer, EgmPeerSettings, check_tolerances
from abb_robot.link import RapidLink, deadline_in, quiet
from abb_robot.settings import AbbRobotSettings
from abb_robot.verbs import RobotVerbs
from cellctl.ports import (
    CartesianPose,
    DeviceDisconnected,
    DeviceProtocolError,
    DeviceRejected,
    DeviceTimeout,
    MotionInterrupted,
)

# How long a session the peer saw end in MCI_ERROR waits for the controller's error reply, which names the cause (s).
FAULT_REPLY_GRACE_S = 0.5


def egm_peer_for(settings: AbbRobotSettings, name: str) -> EgmPeer | None:
    """The sensor-side EGM peer the settings ask for (None when ``egm_port`` is None).

    It prefers the controller's address (``host``): its datagrams are taken whoever else sent first; a
    sender at another address (NAT, a name resolving elsewhere) is taken while the controller is not heard.
    """
    if settings.egm_port is None:
        return None
    return EgmPeer(
        EgmPeerSettings(
            port=settings.egm_port,
            bind_host=settings.egm_bind_host,
            preferred_host=settings.host,
            max_rate_hz=settings.egm_max_rate_hz,
            receive_timeout_s=settings.egm_receive_timeout_s,
            settle_cycles=settings.egm_settle_cycles,
            rt_priority=settings.egm_rt_priority,
            isolation=settings.egm_isolation,
            name=f"{name} EGM",
        )
    )


class EgmSession:
    """EGM pose sessions on one controller.

    Args:
        link: the link the ``EGM`` request goes over.
        verbs: for reading the pose before a correction.
        peer: the sensor-side peer (None: EGM is not configured, every call is refused).
        settings: the correction limits, convergence time and receive timeout.
        streaming: whether a position stream runs (sessions are refused meanwhile).
    """

    def __init__(
        self, link: RapidLink, verbs: RobotVerbs, peer: EgmPeer | None, settings: AbbRobotSettings,
        streaming: Callable[[], bool] = lambda: False,
    ) -> None:
        self.link = link
        self.verbs = verbs
        self.peer = peer
        self.settings = settings
        self.name = link.name
        self._streaming = streaming
        self._running = 0  # corrections and started sessions that have not ended

    @property
    def active(self) -> bool:
        """A correction or a started session runs."""
        return self._running > 0

    def _refuse_while_streaming(self) -> None:
        if self._streaming():
            raise DeviceRejected(
                self.name, "EGM guidance refused: the position stream runs; stop it first (stop_stream)",
                f"{int(P.ErrorCode.BUSY)} BUSY",
            )

    async def start(self, *, band_mm: float, band_deg: float, cond_s: float, timeout_s: float) -> asyncio.Future[None]:
        """Start an EGM pose session (``EGM`` request) and return once it is acknowledged.

        The returned future resolves when the controller ends the session as converged, or
        raises the typed error (ERR 140 after a STOP, ERR 150 after a communication timeout).
        The caller streams references through the peer meanwhile.
        """
        if self.peer is None:
            raise DeviceRejected(self.name, "EGM needs egm_port in the robot's settings")
        self._refuse_while_streaming()
        deadline = deadline_in(timeout_s)
        self._running += 1
        try:
            await self.link.ensure_connected(deadline)
            await self.peer.start(timeout_s=max(deadline - time.monotonic(), 0.001))
            final = await self.link.start_motion("EGM", band_mm, band_deg, cond_s, deadline=deadline)
        except BaseException:
            self._running -= 1
            raise
        loop = asyncio.get_running_loop()
        outcome: asyncio.Future[None] = loop.create_future()

        def ended(_: asyncio.Future[None]) -> None:
            self._running -= 1

        outcome.add_done_callback(ended)

        def settle(f: asyncio.Future[P.Reply]) -> None:
            if outcome.done():
                return
            if f.cancelled():
                outcome.cancel()
            elif f.exception() is not None:
                outcome.set_exception(f.exception())  # type: ignore[arg-type]
            elif f.result().status is P.Status.ERR:
                outcome.set_exception(self.link.error("EGM", f.result()))
            else:
                outcome.set_result(None)

        final.add_done_callback(settle)
        quiet(outcome)  # type: ignore[arg-type]
        return outcome

    async def correct_to(
        self, target: CartesianPose, *, tolerance_mm: float, tolerance_rad: float, timeout_s: float
    ) -> CartesianPose:
        """Fine-correct to ``target`` with EGM and return the reported pose once it converged.

        Starts an EGM pose session on the controller (``EGM`` request; EGMRunPose), streams
        ``target`` from the EGM peer, and returns when the controller ends the session as
        converged (every axis within ``tolerance / sqrt(3)`` for ``egm_cond_time_s``, which
        puts the pose within the tolerances). Corrections larger than
        ``egm_max_correction_mm``/``_deg`` are refused before anything moves.
        """
        if self.peer is None:
            raise DeviceRejected(self.name, "fine correction needs EGM: set egm_port in the robot's settings")
        check_tolerances(tolerance_mm, tolerance_rad)
        self._refuse_while_streaming()
        self._running += 1
        try:
            return await self._correct(target, tolerance_mm, tolerance_rad, timeout_s)
        finally:
            self._running -= 1

    async def _correct(
        self, target: CartesianPose, tolerance_mm: float, tolerance_rad: float, timeout_s: float
    ) -> CartesianPose:
        s = self.settings
        peer = self.peer
        assert peer is not None
        deadline = deadline_in(timeout_s)
        await self.link.ensure_connected(deadline)
        current = await self.verbs.read_pose_by(deadline, reconnect=False)
        dist = math.dist(current.position_mm, target.position_mm)
        angle = math.degrees(unit_quaternion.angle_between(current.quaternion_wxyz, target.quaternion_wxyz))
        if dist > s.egm_max_correction_mm or angle > s.egm_max_correction_deg:
            raise DeviceRejected(
                self.name,
                f"EGM correction of {dist:.2f} mm / {angle:.3f} deg exceeds egm_max_correction_mm="
                f"{s.egm_max_correction_mm:g} / egm_max_correction_deg={s.egm_max_correction_deg:g}; use move()",
                "LIMIT",
            )
        # the EGM process starts only for a correction that will run (refused ones do not wait for it)
        await peer.start(timeout_s=max(deadline - time.monotonic(), 0.001))
        session_before = peer.snapshot().session
        generation = peer.set_reference(target, tolerance_mm=tolerance_mm, tolerance_rad=tolerance_rad)
        band_mm = tolerance_mm / math.sqrt(3.0)
        band_deg = math.degrees(tolerance_rad) / math.sqrt(3.0)
        try:
            final = await self.link.start_motion("EGM", band_mm, band_deg, s.egm_cond_time_s, deadline=deadline)
            await self._supervise(final, session_before, deadline, timeout_s)
            reply = final.result()
            if reply.status is P.Status.ERR:
                raise self.link.error("EGM", reply)
            snap = peer.snapshot()
            if snap.feedback is None or snap.session <= session_before or snap.reference_generation != generation:
                raise DeviceProtocolError(self.name, "EGM session reported done without any EGM data")
            fb = snap.feedback
            d = math.dist(fb.position_mm, target.position_mm)
            a = unit_quaternion.angle_between(fb.quaternion_wxyz, target.quaternion_wxyz)
            if d > tolerance_mm or a > tolerance_rad:
                raise MotionInterrupted(
                    self.name,
                    f"EGM session ended as converged but the reported pose is {d:.3f} mm / {math.degrees(a):.3f} deg "
                    "from the target",
                )
            return fb
        finally:
            peer.clear_reference()

    async def _supervise(
        self, final: asyncio.Future[P.Reply], session_before: int, deadline: float, timeout_s: float
    ) -> None:
        """Wait for the session's end; STOP it on a peer fault, on no EGM data, or at the deadline."""
        s = self.settings
        peer = self.peer
        assert peer is not None
        t_ack = time.monotonic()
        while not final.done():
            died = peer.died()
            if died is not None:
                await self.link.stop_quietly()
                raise DeviceDisconnected(self.name, f"EGM correction stopped: {died}; the next EGM use starts it again")
            snap = peer.snapshot()
            now = time.monotonic()
            if snap.session > session_before and snap.received_at is not None:
                if snap.fault is not None:
                    why = await self._controller_says(final, deadline)
                    await self.link.stop_quietly()
                    raise MotionInterrupted(self.name, f"EGM correction stopped: {snap.fault}{why}")
            elif now - t_ack > s.egm_receive_timeout_s:
                await self.link.stop_quietly()
                raise DeviceTimeout(
                    self.name,
                    f"no EGM data on UDP port {peer.port} within {s.egm_receive_timeout_s:g} s of the session start: "
                    "check the controller's UDPUC remote address and port and the PC firewall",
                )
            if now >= deadline:
                err = snap.position_error_mm
                await self.link.stop_quietly()
                detail = "" if err is None else f"; last error {err:.3f} mm"
                raise DeviceTimeout(self.name, f"EGM correction did not converge within {timeout_s:g} s{detail}")
            await asyncio.wait({final}, timeout=0.004)

    async def _controller_says(self, final: asyncio.Future[P.Reply], deadline: float) -> str:
        """Why the controller ended the session, from its error reply to the ``EGM`` request ("" if none comes
        within ``FAULT_REPLY_GRACE_S``): the EGM datagrams only say MCI_ERROR, the RAPID module's reply names
        the cause (ERR 150 for no data from the sensor, 152 for a state or a reference it refused)."""
        await asyncio.wait({final}, timeout=min(FAULT_REPLY_GRACE_S, max(deadline - time.monotonic(), 0.0)))
        if not final.done() or final.cancelled() or final.exception() is not None:
            return ""
        reply = final.result()
        if reply.status is not P.Status.ERR:
            return ""
        return f"; the controller says: {self.link.error('EGM', reply).message}"
