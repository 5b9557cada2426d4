"""The asyncio client of the RAPID server module: :class:`AbbRobot` implements
:class:`cellctl.ports.Robot`, :class:`cellctl.ports.Identified` and, through EGM,
:class:`cellctl.ports.FineCorrection` and :class:`cellctl.ports.PoseStream`.

It is the composition of the driver's layers, kept apart as ABB keeps its own:

- :mod:`abb_robot.link`: the connection, the framing, request/reply multiplexing by id, the
  heartbeat and background reconnection, and the typed errors of ERR replies;
- :mod:`abb_robot.verbs`: the robot commands on the link (settings kept across reconnections,
  moves, queries);
- :mod:`abb_robot.egm_session`: EGM sessions started on the link and streamed by the
  sensor-side :class:`~abb_robot.egm.peer.EgmPeer`;
- :mod:`abb_robot.egm_stream`: EGM's position stream (the robot's feedback every 4 ms while it
  moves), collected by the same peer;
- :mod:`abb_robot.settings`: :class:`AbbRobotSettings`.

Every call has a deadline (its ``timeout_s``) that covers everything it does, reconnecting
included; nothing waits without one.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

from abb_robot import protocol as P
from abb_robot.egm.peer import EgmPeer
from abb_robot.egm_session import EgmSession, egm_peer_for
from abb_robot.egm_stream import EgmStream, PoseStreamRecords, PoseStreamStats
from abb_robot.link import ControllerInfo, RapidLink
from abb_robot.settings import AbbRobotSettings
from abb_robot.verbs import RobotVerbs
from cellctl.ports import CartesianPose, MotionRequest, PoseSample, RobotState

__all__ = ["AbbRobot", "AbbRobotSettings", "ControllerInfo"]


class AbbRobot:
    """An ABB robot behind ``CellctlServer.mod`` (and EGM). See the module docstring.

    Args:
        settings: connection and motion settings.
        name: the device's name in errors and logs.
        clock: the clock the position stream's samples are given on (s; the cell's clock, which must
            run at the rate of ``time.monotonic``; on hardware it is ``time.monotonic``).
    """

    def __init__(
        self, settings: AbbRobotSettings, *, name: str = "robot", clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.settings = settings
        self.name = name
        self._link = RapidLink(settings, name=name, on_connect=lambda deadline: self._verbs.resync(deadline))
        self._verbs = RobotVerbs(self._link, settings)
        self._peer = egm_peer_for(settings, name)
        self._egm = EgmSession(self._link, self._verbs, self._peer, settings, streaming=lambda: self._stream.active)
        self._stream = EgmStream(self._link, self._peer, clock=clock, guidance_active=lambda: self._egm.active)

    # ------------------------------------------------------------------------------------------
    # connection

    @property
    def info(self) -> ControllerInfo | None:
        """What the controller said in its last HELLO answer (None before the first connection)."""
        return self._link.info

    @property
    def connections(self) -> int:
        """How many TCP connections were made so far (reconnections included)."""
        return self._link.connections

    @property
    def connected(self) -> bool:
        """The link to the controller is up."""
        return self._link.connected

    @property
    def egm(self) -> EgmPeer | None:
        """The EGM peer (None when EGM is not configured)."""
        return self._peer

    def identity(self) -> dict[str, str]:
        """What this robot is (:class:`cellctl.ports.Identified`): the controller's address, and its
        robot type and RobotWare version from the last HELLO answer ("" before the first connection)."""
        info = self.info
        return {
            "host": self.settings.host,
            "rapid_port": str(self.settings.rapid_port),
            "robot_type": "" if info is None else info.robot_type,
            "rw_version": "" if info is None else info.rw_version,
        }

    async def connect(self, *, timeout_s: float | None = None) -> None:
        """Connect, shake hands and send the settings now; optional: the first request does the same.

        The link's heartbeat starts with its first connection, made here or by that request.
        ``timeout_s`` bounds the link and the handshake. EGM is not started here: its peer binds
        its port when the first EGM session needs it (nothing runs that no step uses).
        """
        deadline = time.monotonic() + (timeout_s if timeout_s is not None else self.settings.connect_timeout_s
                                       + self.settings.request_timeout_s)
        await self._link.ensure_connected(deadline)

    async def close(self) -> None:
        """Say BYE, close the link and the EGM port, stop the heartbeat. Safe to call twice."""
        if self._link.closed:
            return
        self._stream.discard()  # BYE ends the stream on the controller
        await self._link.close()
        if self._peer is not None:
            await self._peer.close()

    async def _request(self, verb: str, *args: object, deadline: float, reconnect: bool = True) -> list[P.Reply]:
        """Send one request and return its reply lines (the last one final); ERR raises."""
        return await self._link.request(verb, *args, deadline=deadline, reconnect=reconnect)

    # ------------------------------------------------------------------------------------------
    # settings

    async def set_tool(self, name: str, *, timeout_s: float) -> None:
        """Select a tooldata by name (kept across reconnections)."""
        await self._verbs.set_tool(name, timeout_s=timeout_s)

    async def set_wobj(self, name: str, *, timeout_s: float) -> None:
        """Select a wobjdata by name (kept across reconnections)."""
        await self._verbs.set_wobj(name, timeout_s=timeout_s)

    async def set_speed(self, speed_mm_s: float, speed_deg_s: float, *, timeout_s: float) -> None:
        """TCP and reorientation speed of later moves (kept across reconnections)."""
        await self._verbs.set_speed(speed_mm_s, speed_deg_s, timeout_s=timeout_s)

    async def set_zone(self, zone_mm: float, *, timeout_s: float) -> None:
        """Zone of later moves; 0 is a fine point. DONE of a non-fine move comes when RAPID moves on."""
        await self._verbs.set_zone(zone_mm, timeout_s=timeout_s)

    # ------------------------------------------------------------------------------------------
    # Robot

    async def move(self, request: MotionRequest, *, timeout_s: float) -> CartesianPose:
        """Move to the target (fine point) and return the pose read back after it."""
        return await self._verbs.move(request, timeout_s=timeout_s)

    async def read_pose(self, *, timeout_s: float) -> CartesianPose:
        """The flange pose as the controller reports it."""
        return await self._verbs.read_pose(timeout_s=timeout_s)

    async def read_joints(self, *, timeout_s: float) -> tuple[float, ...]:
        """The six joint angles in radians."""
        return await self._verbs.read_joints(timeout_s=timeout_s)

    async def state(self, *, timeout_s: float) -> RobotState:
        """Motors, motion and joints."""
        return await self._verbs.state(timeout_s=timeout_s)

    async def stop(self, *, timeout_s: float) -> None:
        """Stop whatever motion runs (harmless when none does); a position stream ends with it (the
        module's STOP ends it, and STREAM is refused while the robot decelerates)."""
        await self._verbs.stop(timeout_s=timeout_s)
        await self._stream.ended_by_controller()

    async def set_gripper(self, hold: bool, *, timeout_s: float) -> None:
        """Vacuum on (``hold``) or off (release); refused while the robot moves (see
        :meth:`RobotVerbs.set_gripper`)."""
        await self._verbs.set_gripper(hold, timeout_s=timeout_s)

    async def ping(self, *, timeout_s: float) -> float:
        """A PING round trip; returns its duration in seconds."""
        return await self._verbs.ping(timeout_s=timeout_s)

    # ------------------------------------------------------------------------------------------
    # FineCorrection (EGM)

    async def start_egm_session(
        self, *, band_mm: float, band_deg: float, cond_s: float, timeout_s: float
    ) -> asyncio.Future[None]:
        """Start an EGM pose session and return once it is acknowledged (see :meth:`EgmSession.start`).

        The returned future resolves when the controller ends the session as converged, or
        raises the typed error. The caller streams references through :attr:`egm` meanwhile.
        """
        return await self._egm.start(band_mm=band_mm, band_deg=band_deg, cond_s=cond_s, timeout_s=timeout_s)

    async def correct_to(
        self, target: CartesianPose, *, tolerance_mm: float, tolerance_rad: float, timeout_s: float
    ) -> CartesianPose:
        """Fine-correct to ``target`` with EGM; returns the reported pose once it converged
        (see :meth:`EgmSession.correct_to`)."""
        return await self._egm.correct_to(target, tolerance_mm=tolerance_mm, tolerance_rad=tolerance_rad,
                                          timeout_s=timeout_s)

    # ------------------------------------------------------------------------------------------
    # PoseStream (EGM position stream)

    def stream_unavailable(self) -> str | None:
        """Why the position stream cannot run (None: it can): it needs EGM (``egm_port``)."""
        return None if self._peer is not None else "EGM is not configured (egm_port in the robot's settings)"

    async def start_stream(self, *, timeout_s: float) -> None:
        """Start the position stream (``STREAM 1``; the EGM peer starts on demand); the previous
        collection is dropped. Refused while the robot moves, during an EGM guidance session, and
        without ``egm_port`` (see :mod:`abb_robot.egm_stream`)."""
        await self._stream.start(timeout_s=timeout_s)

    async def stop_stream(self, *, timeout_s: float) -> tuple[PoseSample, ...]:
        """Stop the position stream (``STREAM 0``); its samples (TCP pose, instant on the driver's clock) in time order."""
        return await self._stream.stop(timeout_s=timeout_s)

    def latest(self) -> PoseSample | None:
        """The newest sample of the running position stream (None before its first, and when none runs)."""
        return self._stream.latest()

    @property
    def stream_stats(self) -> PoseStreamStats:
        """What the running (or last) position stream delivered: samples, lost datagrams, the tm mapping."""
        return self._stream.stats()

    def stream_records(self) -> PoseStreamRecords:
        """The running (or last) position stream's datagrams: seqno, tm, feedBack.time, receive time, pose."""
        return self._stream.records()
