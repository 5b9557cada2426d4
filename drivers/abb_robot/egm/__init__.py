"""EGM (Externally Guided Motion): the project's schema (``egm.proto``), its generated module
(``egm_pb2``) and the sensor-side UDP peer (:class:`EgmPeer`; its settings and reports in
:mod:`abb_robot.egm.peer_types`).

``egm_pb2.py`` is generated and committed; regenerate it from ``drivers/`` with::

    python -m grpc_tools.protoc -I . --python_out=. abb_robot/egm/egm.proto

(tests/drivers/test_abb_egm_proto.py checks that this gives the committed file byte for byte).
"""

from abb_robot.egm.peer import EgmPeer
from abb_robot.egm.peer_types import EgmPeerSettings, EgmPeerStats, EgmSnapshot

__all__ = ["EgmPeer", "EgmPeerSettings", "EgmPeerStats", "EgmSnapshot"]
