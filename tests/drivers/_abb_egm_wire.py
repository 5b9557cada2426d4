"""EgmRobot datagrams encoded by hand on the protobuf wire, from the field numbers of ABB's egm.proto.

Independent of the project's ``egm.proto``/``egm_pb2`` (the code under test): EgmRobot header = 1
(EgmHeader: seqno = 1, tm = 2, mtype = 3), feedBack = 2 (EgmFeedBack: joints = 1, cartesian = 2
(EgmPose: pos = 1 (x y z = 1 2 3, double), orient = 2 (u0..u3 = 1..4, double)), time = 4 (EgmClock:
sec = 1, usec = 2)), motorState = 4, mciState = 5, rapidExecState = 8 (each: state = 1).
"""

from __future__ import annotations

import struct

MSGTYPE_DATA = 2
MOTORS_ON = 1
MCI_STOPPED, MCI_RUNNING = 2, 3
RAPID_RUNNING = 2


def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        byte, n = n & 0x7F, n >> 7
        out.append(byte | (0x80 if n else 0))
        if not n:
            return bytes(out)


def _uint(field: int, n: int) -> bytes:
    return _varint(field << 3) + _varint(n)  # wire type 0; written even when 0 (proto2: the field is present)


def _double(field: int, x: float) -> bytes:
    return _varint(field << 3 | 1) + struct.pack("<d", x)


def _sub(field: int, body: bytes) -> bytes:
    return _varint(field << 3 | 2) + _varint(len(body)) + body


def egm_robot(
    seq: int, tm_ms: int, x_mm: float, *, y_mm: float = 0.0, z_mm: float = 1000.0, mci: int = MCI_RUNNING,
    wall_s: float | None = None,
) -> bytes:
    """One EgmRobot: seqno, ``header.tm`` (ms, u32), MSGTYPE_DATA, the TCP at (x, y, z) mm with a unit
    orientation, six zero joints, motors on, RAPID running, MCI state ``mci``, ``feedBack.time`` if given."""
    header = _uint(1, seq & 0xFFFFFFFF) + _uint(2, tm_ms & 0xFFFFFFFF) + _uint(3, MSGTYPE_DATA)
    pose = _sub(1, _double(1, x_mm) + _double(2, y_mm) + _double(3, z_mm))
    pose += _sub(2, _double(1, 1.0) + _double(2, 0.0) + _double(3, 0.0) + _double(4, 0.0))
    feedback = _sub(1, b"".join(_double(1, 0.0) for _ in range(6))) + _sub(2, pose)
    if wall_s is not None:
        sec = int(wall_s)
        feedback += _sub(4, _uint(1, sec) + _uint(2, int((wall_s - sec) * 1e6)))
    return (_sub(1, header) + _sub(2, feedback) + _sub(4, _uint(1, MOTORS_ON)) + _sub(5, _uint(1, mci))
            + _sub(8, _uint(1, RAPID_RUNNING)))


def _read_varint(data: bytes, i: int) -> tuple[int, int]:
    n = shift = 0
    while True:
        byte = data[i]
        n |= (byte & 0x7F) << shift
        i, shift = i + 1, shift + 7
        if not byte & 0x80:
            return n, i


def _fields(data: bytes) -> dict[int, int | bytes]:
    """The top-level fields of a message (varints and length-delimited ones; the last of each number)."""
    out: dict[int, int | bytes] = {}
    i = 0
    while i < len(data):
        key, i = _read_varint(data, i)
        field, wire = key >> 3, key & 7
        if wire == 0:
            out[field], i = _read_varint(data, i)
        elif wire == 1:
            out[field], i = data[i : i + 8], i + 8
        elif wire == 2:
            n, i = _read_varint(data, i)
            out[field], i = data[i : i + n], i + n
        elif wire == 5:
            out[field], i = data[i : i + 4], i + 4
        else:
            raise ValueError(f"wire type {wire}")
    return out


def reply_seqno(data: bytes) -> int:
    """``header.seqno`` of an EgmSensor (header = 1, seqno = 1, as in EgmRobot)."""
    header = _fields(data)[1]
    assert isinstance(header, bytes)
    seqno = _fields(header)[1]
    assert isinstance(seqno, int)
    return seqno
