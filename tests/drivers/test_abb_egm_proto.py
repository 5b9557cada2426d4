"""The EGM schema: the committed module is what protoc generates, tags match ABB's, and it
coexists and interoperates with ABB's own egm.proto in one process."""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from abb_robot.egm import egm_pb2 as pb

DRIVERS = Path(__file__).resolve().parents[2] / "drivers"
REFERENCE_PROTO = Path(__file__).resolve().parents[3] / "shared" / "reference" / "egm.proto"


def test_committed_module_is_what_protoc_generates(tmp_path: Path) -> None:
    pytest.importorskip("grpc_tools", reason="grpcio-tools (dev extra) regenerates egm_pb2.py")
    src = tmp_path / "abb_robot" / "egm"
    src.mkdir(parents=True)
    shutil.copy(DRIVERS / "abb_robot" / "egm" / "egm.proto", src / "egm.proto")
    subprocess.run(
        [sys.executable, "-m", "grpc_tools.protoc", "-I", str(tmp_path), f"--python_out={tmp_path}",
         "abb_robot/egm/egm.proto"],
        check=True, timeout=60,
    )
    generated = (src / "egm_pb2.py").read_text(encoding="utf-8")
    committed = (DRIVERS / "abb_robot" / "egm" / "egm_pb2.py").read_text(encoding="utf-8")
    assert generated == committed, "egm_pb2.py is stale: regenerate it (see abb_robot/egm/__init__.py)"


def _tags(message: type) -> dict[str, tuple[int, int]]:
    return {f.name: (f.number, f.type) for f in message.DESCRIPTOR.fields}


def test_tags_and_types_are_abbs() -> None:
    F = pb.EgmRobot.DESCRIPTOR.fields_by_name["header"].__class__  # FieldDescriptor
    d, u32, b, msg, enum = F.TYPE_DOUBLE, F.TYPE_UINT32, F.TYPE_BOOL, F.TYPE_MESSAGE, F.TYPE_ENUM
    assert _tags(pb.EgmHeader) == {"seqno": (1, u32), "tm": (2, u32), "mtype": (3, enum)}
    assert _tags(pb.EgmRobot) == {
        "header": (1, msg), "feedBack": (2, msg), "planned": (3, msg), "motorState": (4, msg),
        "mciState": (5, msg), "mciConvergenceMet": (6, b), "testSignals": (7, msg), "rapidExecState": (8, msg),
        "measuredForce": (9, msg), "utilizationRate": (10, d), "moveIndex": (11, u32), "CollisionInfo": (12, msg),
        "RAPIDfromRobot": (13, msg),
    }
    assert _tags(pb.EgmSensor) == {"header": (1, msg), "planned": (2, msg), "speedRef": (3, msg), "RAPIDtoRobot": (4, msg)}
    assert _tags(pb.EgmQuaternion) == {f"u{i}": (i + 1, d) for i in range(4)}
    assert _tags(pb.EgmPose) == {"pos": (1, msg), "orient": (2, msg), "euler": (3, msg)}
    assert pb.EgmHeader.MSGTYPE_CORRECTION == 3 and pb.EgmMCIState.MCI_RUNNING == 3
    assert pb.EgmMotorState.MOTORS_OFF == 2 and pb.EgmRapidCtrlExecState.RAPID_RUNNING == 2


def test_coexists_and_interoperates_with_abbs_schema(tmp_path: Path) -> None:
    pytest.importorskip("grpc_tools", reason="grpcio-tools (dev extra) compiles ABB's schema for the check")
    if not REFERENCE_PROTO.exists():
        pytest.skip(f"ABB's egm.proto is not beside the repository ({REFERENCE_PROTO})")
    shutil.copy(REFERENCE_PROTO, tmp_path / "egm.proto")
    subprocess.run(
        [sys.executable, "-m", "grpc_tools.protoc", "-I", str(tmp_path), f"--python_out={tmp_path}", "egm.proto"],
        check=True, timeout=60,
    )
    spec = importlib.util.spec_from_file_location("abb_reference_egm_pb2", tmp_path / "egm_pb2.py")
    assert spec is not None and spec.loader is not None
    abb = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(abb)  # same process as ours: no descriptor-pool clash

    ours = pb.EgmRobot()
    ours.header.seqno, ours.header.tm, ours.header.mtype = 41, 164, pb.EgmHeader.MSGTYPE_DATA
    ours.feedBack.cartesian.pos.x, ours.feedBack.cartesian.pos.y, ours.feedBack.cartesian.pos.z = 1.5, -2.25, 3.0
    o = ours.feedBack.cartesian.orient
    o.u0, o.u1, o.u2, o.u3 = 0.5, 0.5, -0.5, 0.5
    ours.feedBack.joints.joints.extend([1, 2, 3, 4, 5, 6])
    ours.mciState.state = pb.EgmMCIState.MCI_RUNNING
    ours.motorState.state = pb.EgmMotorState.MOTORS_ON
    ours.mciConvergenceMet = True
    ours.utilizationRate = 12.5
    theirs = abb.EgmRobot.FromString(ours.SerializeToString())
    assert (theirs.header.seqno, theirs.header.tm, theirs.header.mtype) == (41, 164, 2)
    c = theirs.feedBack.cartesian
    assert (c.pos.x, c.pos.y, c.pos.z) == (1.5, -2.25, 3.0)
    assert (c.orient.u0, c.orient.u1, c.orient.u2, c.orient.u3) == (0.5, 0.5, -0.5, 0.5)
    assert list(theirs.feedBack.joints.joints) == [1, 2, 3, 4, 5, 6]
    assert theirs.mciState.state == 3 and theirs.motorState.state == 1
    assert theirs.mciConvergenceMet and theirs.utilizationRate == 12.5

    reply = abb.EgmSensor()
    reply.header.seqno, reply.header.mtype = 7, 3
    p = reply.planned.cartesian
    p.pos.x, p.pos.y, p.pos.z = 10.0, 20.0, 30.0
    p.orient.u0, p.orient.u1, p.orient.u2, p.orient.u3 = 1.0, 0.0, 0.0, 0.0
    back = pb.EgmSensor.FromString(reply.SerializeToString())
    assert back.header.seqno == 7 and back.header.mtype == pb.EgmHeader.MSGTYPE_CORRECTION
    assert (back.planned.cartesian.pos.x, back.planned.cartesian.pos.z) == (10.0, 30.0)
    assert back.planned.cartesian.orient.u0 == 1.0
