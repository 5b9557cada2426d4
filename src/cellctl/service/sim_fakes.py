"""The simulated cell with real drivers: the LK-G and ABB protocol fakes, their physics from the twin.

Part of the simulated cell's composition root (it imports drivers and the twin). The fakes keep their own wire format and time;
the twin (:class:`cellctl.sim.cell.SimCell`) supplies what a real sensor and arm would do:
the laser's status and distance where the flange truly stands, and the true pose an arm reaches
for a commanded (belief) target, and the glass let go where it truly stands when the gripper
releases it. The controller reports the belief back, as a real one does.
"""

from __future__ import annotations

import random
import socket
from collections.abc import Awaitable, Callable
from typing import Literal

from abb_robot import AbbRobot, AbbRobotSettings
from abb_robot.fake.controller import FakeController, FakeControllerConfig
from abb_robot.fake.model import SimpleArmModel, TimedMove, Unreachable
from keyence_lkg import KeyenceLkgSensor
from keyence_lkg.fake import FakeLkgController

from cellctl.config.devices import SimAbbDevice, SimKeyenceLkgDevice
from cellctl.geometry.pose import Pose
from cellctl.ports import CartesianPose, LaserStatus
from cellctl.sim.cell import SimCell
from cellctl.sim.robot import ReachError

Closer = Callable[[], Awaitable[None]]


class TwinArmModel:
    """The ABB fake's robot model over the twin's arm (reach, timing, accuracy field and noise), which moves in time."""

    def __init__(self, cell: SimCell) -> None:
        self._cell = cell
        # Joint angles for GETJ and EGM's feedback only: the twin models no joints (its reach is the check), so
        # no axis limit of the simple arm may refuse a pose the twin reaches.
        self._joints = SimpleArmModel(seed=cell.seed, limits_deg=((-180.0, 180.0),) * 6)

    def reachable(self, target: CartesianPose) -> Unreachable | None:
        try:
            self._cell.robot_model.check_reach(target.to_matrix())
        except ReachError as err:
            return Unreachable("reach", str(err))
        return None

    def motion_time(
        self, start: CartesianPose, target: CartesianPose, speed_mm_s: float, speed_deg_s: float, linear: bool
    ) -> float:
        """The move's simulated seconds (a question only: :meth:`begin` puts a move on the twin's time line)."""
        return self._cell.motion_time(start.to_matrix(), target.to_matrix(), speed_mm_s, speed_deg_s)

    def execute(self, target: CartesianPose) -> CartesianPose:
        self._cell.execute(target.to_matrix())  # the twin's arm now truly stands there (with its errors)
        return target  # the controller reports its belief

    def begin(
        self, start: CartesianPose, target: CartesianPose, speed_mm_s: float, speed_deg_s: float, time_scale: float
    ) -> TimedMove:
        """A RAPID move on the twin's arm in time: the laser reads where the arm truly is along it, the
        controller reports the arm's belief (both on the fake's clock, time.monotonic, as the arm's).

        The arm moves at the fake's ``time_scale`` (a test may change the fake's). Only the target's
        reach is checked, as the fake checks a MoveL's. A move the fake's timer ended a hair before
        the arm's settling is ended where it stands (on its target: the path is done while it settles).
        """
        arm = self._cell.arm
        if arm.moving():
            arm.stop()
        if not (arm.time_scale == 0.0 and time_scale <= 1e-6):  # the fake's floor for an instant twin
            arm.time_scale = time_scale
        motion = arm.start(target.to_matrix(), speed_mm_s, speed_deg_s, linear=False)
        return TimedMove(motion.duration_s, motion.t_start, lambda now: CartesianPose.from_matrix(motion.belief_at(now)))

    def halt(self) -> CartesianPose:
        return CartesianPose.from_matrix(self._cell.arm.stop())

    def joints(self, pose: CartesianPose) -> tuple[float, ...]:
        return self._joints.joints(pose)


LKG_DISPLACEMENT_POSITIVE: Literal["away_from_head"] = "away_from_head"
"""Which way the fake's (and so the driver's) positive displacement points."""


def lkg_reference_mm(cell: SimCell) -> float:
    """The distance along the laser at which the fake's OUT reads 0: the middle of the twin's range."""
    laser = cell.config.laser
    return 0.5 * (laser.range_min_mm + laser.range_max_mm)


class TwinLaserSource:
    """The twin's laser where the flange truly is: now, or at a past instant of time.monotonic() (for the storage)."""

    def __init__(self, cell: SimCell) -> None:
        self._cell = cell

    def __call__(self) -> float | LaserStatus:
        return self._distance(self._cell.laser_reading())

    def at(self, t: float) -> float | LaserStatus:
        try:  # the arm's clock is time.monotonic (the fakes'): the twin's time line may have stood still since t
            return self._distance(self._cell.laser_reading(self._cell.arm.true_at_clock(t)))
        except LookupError:  # older than the arm remembers
            return self()

    @staticmethod
    def _distance(reading: tuple[LaserStatus, float | None]) -> float | LaserStatus:
        status, d = reading
        return d if status is LaserStatus.OK and d is not None else status


def lkg_fake(cell: SimCell, dialect: str, display_unit: str) -> FakeLkgController:
    """The LK-G protocol fake on a new pseudo-terminal (started), reading the twin's laser where the flange truly is."""
    laser = cell.config.laser
    return FakeLkgController(
        dialect,
        TwinLaserSource(cell),
        display_unit=display_unit,
        reference_distance_mm=lkg_reference_mm(cell),
        measuring_range_mm=0.5 * laser.full_scale_mm,
        displacement_positive=LKG_DISPLACEMENT_POSITIVE,
    ).start()


def lkg_on_fake(cell: SimCell, dev: SimKeyenceLkgDevice, fakes: dict[str, object] | None = None) -> tuple[KeyenceLkgSensor, Closer]:
    """The real LK-G driver on a pseudo-terminal served by the fake controller (kept in ``fakes["laser"]``)."""
    fake = lkg_fake(cell, dev.dialect, dev.display_unit)
    if fakes is not None:
        fakes["laser"] = fake  # faults are injected here (silence, garble, vanish)
    driver = KeyenceLkgSensor.from_config(
        {
            "port": fake.path,
            "dialect": dev.dialect,
            "display_unit": dev.display_unit,
            "reference_distance_mm": lkg_reference_mm(cell),
            "displacement_positive": LKG_DISPLACEMENT_POSITIVE,
            "exchange_timeout_s": dev.exchange_timeout_s,
        },
        clock=cell.timeline.now,  # the cell's clock: the storage's start on it, as the cell pairs on it
    )

    async def close() -> None:
        await driver.close()
        fake.stop()

    return driver, close


def abb_fake(cell: SimCell, *, time_scale: float | None = None, egm_sensor_port: int | None = None) -> FakeController:
    """The ABB fake controller (RAPID line server on a free loopback port; EGM to ``egm_sensor_port`` on
    loopback, if given) moving the twin's arm: where a RAPID move or an EGM session leaves it.

    Its GRIP switches the twin's gripper (``SimCell.set_gripper``), called from the fake's thread
    under its robot's lock as the model's ``execute`` is. Not started: :meth:`FakeController.start` (in a loop) or :meth:`FakeController.start_in_thread`.
    ``time_scale`` overrides the twin's (real seconds per simulated second).
    """
    scale = cell.time_scale if time_scale is None else time_scale
    return FakeController(
        FakeControllerConfig(
            rapid_port=0,
            egm_sensor_port=egm_sensor_port,
            time_scale=max(scale, 1e-6),
            home=CartesianPose.from_matrix(cell.belief_flange_pose()),
            seed=cell.seed,
            gripper_hold=cell.glass_on_gripper,
            gripper_settle_s=cell.config.robot.gripper_settle_s,
            on_gripper=lambda hold: _grip(cell, hold),
        ),
        TwinArmModel(cell),
    )


# Where the twin's EGM ports are drawn: below the kernel's ephemeral range, apart from the tests' stripes (20000 up).
EGM_PORTS = range(10000, 20000)


def free_udp_port() -> int:
    """A UDP port free on loopback now, for the EGM peer, which binds it at the first EGM use, maybe minutes later.

    Drawn from ``EGM_PORTS``, never from the ephemeral range: a port the kernel hands out for ``bind(0)`` can go
    to another socket meanwhile, such as another twin's fake controller sending EGM, whose datagrams this cell's
    peer would then take for its controller's.
    """
    for port in random.sample(EGM_PORTS, 200):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    raise RuntimeError(f"no free loopback UDP port in {EGM_PORTS.start}-{EGM_PORTS.stop - 1} for the twin's EGM")


def _grip(cell: SimCell, hold: bool) -> None:
    """The fake's GRIP on the twin: the gripper switches, and its settling goes on the twin's time line."""
    cell.set_gripper(hold)
    cell.timeline.waited(cell.config.robot.gripper_settle_s, "gripper")


def abb_on_fake(
    cell: SimCell, dev: SimAbbDevice, fakes: dict[str, object] | None = None
) -> tuple[AbbRobot, Closer, Callable[[Pose], None]]:
    """The real ABB client talking to the fake controller (its own thread and loop) on loopback.

    Also returns the fake's teach-pendant jog (the simulated operator guides the robot with it);
    the fake itself is kept in ``fakes["robot"]`` (faults: drop the client, refuse, delay).
    """
    egm_port = free_udp_port() if dev.egm else None
    fake = abb_fake(cell, egm_sensor_port=egm_port)
    if fakes is not None:
        fakes["robot"] = fake
    port = fake.start_in_thread()
    driver = AbbRobot(
        AbbRobotSettings(
            host="127.0.0.1",
            rapid_port=port,
            egm_port=egm_port,
            egm_bind_host="127.0.0.1",
            egm_isolation="thread",
            request_timeout_s=dev.request_timeout_s,
            heartbeat_period_s=dev.heartbeat_period_s,
        ),
        clock=cell.timeline.now,  # the cell's clock: the position stream's samples on it, as the cell pairs on it
    )

    async def close() -> None:
        await driver.close()
        fake.stop_thread()

    def jog(T_B_H: Pose) -> None:
        fake.robot.jog(CartesianPose.from_matrix(T_B_H))

    return driver, close, jog
