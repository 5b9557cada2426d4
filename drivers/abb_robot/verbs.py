"""The robot commands of the line protocol, built on :class:`~abb_robot.link.RapidLink`.

:class:`RobotVerbs` keeps the controller's tool, work object, speed and zone as the cell last
set them and sends them again after every (re)connection (:meth:`RobotVerbs.resync`, the link's
``on_connect`` hook), so a controller that restarted or lost its settings is put back into the
state the cell expects. Moves stage POS and ORI, then run MOVEL or MOVEJ to a fine point and
read the pose back. GRIP switches the gripper's vacuum (never while the robot moves).
"""

from __future__ import annotations

import asyncio
import logging
import math
import time

from abb_robot import protocol as P
from abb_robot import unit_quaternion
from abb_robot.link import RapidLink, deadline_in
from abb_robot.settings import AbbRobotSettings
from cellctl.ports import (
    CartesianPose,
    DeviceBusy,
    DeviceProtocolError,
    DeviceRejected,
    DeviceTimeout,
    MotionRequest,
    RobotState,
)

log = logging.getLogger("abb_robot.client")  # the driver's log, as before the split into modules


class RobotVerbs:
    """Settings, motions and queries over one link.

    Args:
        link: the link to the controller.
        settings: the tool, work object, speed and zone to start from.
    """

    def __init__(self, link: RapidLink, settings: AbbRobotSettings) -> None:
        self.link = link
        self.name = link.name
        self._speed = (settings.speed_mm_s, settings.speed_deg_s)
        self._tool = settings.tool
        self._wobj = settings.wobj
        self._zone = settings.zone_mm
        self._stops = 0  # STOPs asked for so far: a move staged before one is never started

    async def resync(self, deadline: float) -> None:
        """Send tool, work object, speed and zone (after every connection)."""
        for verb, args in (
            ("TOOL", (self._tool,)),
            ("WOBJ", (self._wobj,)),
            ("SPEED", self._speed),
            ("ZONE", (self._zone,)),
        ):
            while True:
                try:
                    await self.link.request(verb, *args, deadline=deadline, reconnect=False, quick=True)
                    break
                except DeviceRejected as exc:
                    # The controller may still be stopping a motion whose client went away.
                    if exc.code != f"{int(P.ErrorCode.BUSY)} BUSY" or time.monotonic() + 0.05 >= deadline:
                        raise
                    await asyncio.sleep(0.05)

    # ------------------------------------------------------------------------------------------
    # settings

    async def set_tool(self, name: str, *, timeout_s: float) -> None:
        """Select a tooldata by name (kept across reconnections)."""
        await self.link.request("TOOL", name, deadline=deadline_in(timeout_s), quick=True)
        self._tool = name

    async def set_wobj(self, name: str, *, timeout_s: float) -> None:
        """Select a wobjdata by name (kept across reconnections)."""
        await self.link.request("WOBJ", name, deadline=deadline_in(timeout_s), quick=True)
        self._wobj = name

    async def set_speed(self, speed_mm_s: float, speed_deg_s: float, *, timeout_s: float) -> None:
        """TCP and reorientation speed of later moves (kept across reconnections)."""
        await self.link.request("SPEED", speed_mm_s, speed_deg_s, deadline=deadline_in(timeout_s), quick=True)
        self._speed = (speed_mm_s, speed_deg_s)

    async def set_zone(self, zone_mm: float, *, timeout_s: float) -> None:
        """Zone of later moves; 0 is a fine point. DONE of a non-fine move comes when RAPID moves on."""
        await self.link.request("ZONE", zone_mm, deadline=deadline_in(timeout_s), quick=True)
        self._zone = zone_mm

    # ------------------------------------------------------------------------------------------
    # motions and queries

    async def move(self, request: MotionRequest, *, timeout_s: float) -> CartesianPose:
        """Move to the target (fine point) and return the pose read back after it.

        ``timeout_s`` bounds the whole move; SPEED, POS, ORI, the motion's ACK and the GETC read-back are each
        answered at once, so each waits ``request_timeout_s`` at most (the heartbeat stands back meanwhile): a
        controller gone silent then fails the move within seconds, naming the request. Only DONE may take long.
        """
        deadline = deadline_in(timeout_s)
        stops = self._stops
        await self.link.ensure_connected(deadline)
        target = request.target
        q = unit_quaternion.normalise(target.quaternion_wxyz)
        speed = (request.speed_mm_s, request.speed_deg_s)
        if speed != self._speed:
            await self.link.request("SPEED", *speed, deadline=deadline, reconnect=False, quick=True)
            self._speed = speed
        await self.link.request("POS", *target.position_mm, deadline=deadline, reconnect=False, quick=True)
        await self.link.request("ORI", *q, deadline=deadline, reconnect=False, quick=True)
        verb = "MOVEL" if request.kind == "linear" else "MOVEJ"
        if self._stops != stops:  # a STOP went out while SPEED, POS and ORI were answered: the motion is not begun
            raise DeviceRejected(self.name, f"{verb} to {_fmt_pose(target)} not started: a STOP came while it was staged")
        final = await self.link.start_motion(verb, deadline=deadline)
        await self.link.finish_motion(verb, final, deadline, f"{verb} to {_fmt_pose(target)}")
        return await self.read_pose_by(deadline, reconnect=False)

    async def read_pose(self, *, timeout_s: float) -> CartesianPose:
        """The flange pose (current tool in the current work object) as the controller reports it."""
        return await self.read_pose_by(deadline_in(timeout_s))

    async def read_pose_by(self, deadline: float, *, reconnect: bool = True) -> CartesianPose:
        """:meth:`read_pose` within an absolute deadline (GETC: DATA POS, then OK ORI; answered at once, so its
        answer is awaited ``request_timeout_s`` at most however far the deadline)."""
        lines = await self.link.request("GETC", deadline=deadline, reconnect=reconnect, quick=True)
        try:
            if len(lines) != 2 or lines[0].status is not P.Status.DATA:
                raise P.ProtocolError(f"GETC answered {len(lines)} line(s), expected DATA POS then OK ORI")
            pos = P.parse_labelled(lines[0].fields, "POS", 3)
            q = P.parse_labelled(lines[1].fields, "ORI", 4)
            return CartesianPose((pos[0], pos[1], pos[2]), unit_quaternion.normalise(q))
        except (P.ProtocolError, ValueError) as exc:
            raise DeviceProtocolError(self.name, f"bad GETC answer: {exc}") from None

    async def read_joints(self, *, timeout_s: float) -> tuple[float, ...]:
        """The six joint angles in radians."""
        return await self._read_joints(deadline_in(timeout_s))

    async def _read_joints(self, deadline: float) -> tuple[float, ...]:
        """GETJ within an absolute deadline, in radians."""
        lines = await self.link.request("GETJ", deadline=deadline, quick=True)
        try:
            return tuple(math.radians(v) for v in P.parse_numbers(lines[-1].fields, 6, "GETJ"))
        except P.ProtocolError as exc:
            raise DeviceProtocolError(self.name, f"bad GETJ answer: {exc}") from None

    async def state(self, *, timeout_s: float) -> RobotState:
        """Motors, motion and joints (STATE, then GETJ)."""
        deadline = deadline_in(timeout_s)
        lines = await self.link.request("STATE", deadline=deadline, quick=True)
        fields = lines[-1].fields
        if len(fields) != 2 or fields[0] not in ("1", "0", "-1") or fields[1] not in ("1", "0"):
            raise DeviceProtocolError(self.name, f"bad STATE answer: {' '.join(fields)!r}")
        if fields[0] == "-1":
            log.warning("%s: the controller has no motors-on signal configured; reporting motors off", self.name)
        joints = await self._read_joints(deadline)
        return RobotState(motors_on=fields[0] == "1", program_running=True, moving=fields[1] == "1", joints_rad=joints)

    async def stop(self, *, timeout_s: float) -> None:
        """Stop whatever motion runs (harmless when none does); a move staged meanwhile is not started."""
        self._stops += 1
        await self.link.request("STOP", deadline=deadline_in(timeout_s), quick=True)

    async def set_gripper(self, hold: bool, *, timeout_s: float) -> None:
        """GRIP 1 (vacuum on, hold the glass) or GRIP 0 (off, release it); returns once the
        controller has switched its output and waited the vacuum's settle time.

        Raises DeviceRejected while a motion or EGM session runs (code 110 BUSY: the glass is
        never released mid-motion, the output keeps its value) or when the controller cannot
        switch the output (code 160 GRIPPER); DeviceTimeout when the answer does not come within
        ``timeout_s`` (which must cover the controller's settle time, ``grip_settle``).
        """
        if not isinstance(hold, bool):
            raise TypeError(f"{self.name}: set_gripper needs hold True or False, got {hold!r}")
        what = "hold" if hold else "release"
        value = 1 if hold else 0
        try:
            lines = await self.link.request("GRIP", value, deadline=deadline_in(timeout_s))
        except DeviceRejected as exc:
            if exc.code == f"{int(P.ErrorCode.BUSY)} BUSY":
                raise DeviceRejected(
                    self.name, f"gripper {what} refused: the robot is moving; the gripper keeps its state "
                    "(switch it only at a standstill)", exc.code,
                ) from None
            raise
        except DeviceTimeout as exc:
            raise DeviceTimeout(
                self.name, f"gripper {what} (GRIP {value}) not confirmed within {timeout_s:g} s ({exc.message}); "
                "the output may or may not have switched, GRIP can be sent again",
            ) from None
        fields = lines[-1].fields
        if fields != (str(value),):
            raise DeviceProtocolError(self.name, f"bad GRIP answer: {' '.join(fields)!r} (expected {value})")

    async def ping(self, *, timeout_s: float) -> float:
        """A PING round trip; returns its duration in seconds.

        Raises DeviceBusy, sending nothing, while another request waits for its answer: the controller
        reads no line until it has answered (GRIP waits the gripper's settle time), and that request's
        own deadline watches it meanwhile.
        """
        deadline = deadline_in(timeout_s)
        t0 = time.monotonic()
        busy_with = self.link.waiting_for()
        if busy_with is not None:
            raise DeviceBusy(self.name, f"busy: {busy_with} waits for its answer (under its own deadline); no PING sent")
        await self.link.request("PING", deadline=deadline)
        return time.monotonic() - t0


def _fmt_pose(p: CartesianPose) -> str:
    x, y, z = p.position_mm
    return f"({x:.1f}, {y:.1f}, {z:.1f}) mm"
