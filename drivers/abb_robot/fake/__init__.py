"""A fake ABB controller speaking the real wire protocols, for tests and the simulated cell.

It serves the same line protocol as ``rapid/CellctlServer.mod`` on TCP and plays the robot side
of EGM over UDP (``EgmRobot`` every 4 ms, seqno from 0, the last reference held, the session
ended after the communication timeout; or, after ``STREAM 1``, the Position Stream: the TCP
pose every 4 ms while RAPID moves run, nothing read back). Its robot moves with lag and
repeatability noise and refuses unreachable targets; the physics comes from a
:class:`RobotModel` (default :class:`SimpleArmModel`), so the composition root can plug in the
twin's robot::

    FakeController(FakeControllerConfig(egm_sensor_port=6511), model=twin_robot_model)

A model implements ``reachable(target) -> Unreachable | None``, ``motion_time(start, target,
speed_mm_s, speed_deg_s, linear) -> s``, ``execute(target) -> actual pose`` and
``joints(pose) -> radians``, all on flange poses in the base frame.

Run it in its own process: ``python -m abb_robot.fake --rapid-port P --egm-port Q``.
"""

from abb_robot.fake.controller import DEFAULT_HOME, FakeController, FakeControllerConfig
from abb_robot.fake.egm_robot import EgmDynamics, EgmEnd, EgmSessionStats
from abb_robot.fake.egm_stream import EgmStreamStats
from abb_robot.fake.model import ArmGeometry, RobotModel, SimpleArmModel, Unreachable
from abb_robot.fake.rapid_server import ServerIdentity

__all__ = [
    "ArmGeometry",
    "DEFAULT_HOME",
    "EgmDynamics",
    "EgmEnd",
    "EgmSessionStats",
    "EgmStreamStats",
    "FakeController",
    "FakeControllerConfig",
    "RobotModel",
    "ServerIdentity",
    "SimpleArmModel",
    "Unreachable",
]
