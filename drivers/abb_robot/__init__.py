"""cellctl's ABB robot driver: a RAPID socket server module, its asyncio client, EGM, and a fake.

- ``rapid/CellctlServer.mod`` and ``rapid/CellctlMotion.mod``: the server that runs on the IRC5
  or OmniCore controller (loading and controller configuration: ``README.md`` next to this file).
- :mod:`abb_robot.protocol`: the line protocol, defined once (codec, limits, error codes, the
  README's table).
- :class:`AbbRobot` (:mod:`abb_robot.client`): implements ``cellctl.ports.Robot`` over the line
  protocol, ``cellctl.ports.FineCorrection`` and ``cellctl.ports.PoseStream`` through EGM. It
  composes the layers: :mod:`abb_robot.link` (connection, framing, request multiplexing,
  heartbeat, reconnection), :mod:`abb_robot.verbs` (the robot commands),
  :mod:`abb_robot.egm_session` (EGM sessions), :mod:`abb_robot.egm_stream` (the position stream)
  and :mod:`abb_robot.settings` (:class:`AbbRobotSettings`).
- :mod:`abb_robot.unit_quaternion`: the wire's quaternion convention (unit, w >= 0) and the angle
  between two orientations; conversions to and from matrices are the ports'.
- :mod:`abb_robot.egm`: the EGM schema (``egm.proto``, compiled to ``egm_pb2``) and the
  sensor-side UDP peer :class:`~abb_robot.egm.EgmPeer` (its loop in ``peer_core``, run in a child
  process by ``peer_process``; its settings and reports in ``peer_types``).
- :mod:`abb_robot.fake`: a fake controller serving both protocols, run as
  ``python -m abb_robot.fake --rapid-port P --egm-port Q``.
- :mod:`abb_robot.bench`: ``python -m abb_robot.bench [--seconds 60]``, the EGM loop's rate and
  reply latency against the fake.

From the core this package imports only ``cellctl.ports``.
"""

from abb_robot.client import AbbRobot
from abb_robot.egm.peer import EgmPeer
from abb_robot.egm.peer_types import EgmPeerSettings, EgmSnapshot
from abb_robot.link import ControllerInfo
from abb_robot.protocol import PROTOCOL_VERSION, ErrorCode
from abb_robot.settings import AbbRobotSettings

__all__ = [
    "PROTOCOL_VERSION",
    "AbbRobot",
    "AbbRobotSettings",
    "ControllerInfo",
    "EgmPeer",
    "EgmPeerSettings",
    "EgmSnapshot",
    "ErrorCode",
]
