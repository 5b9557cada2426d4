"""Modbus TCP requests as bytes on the wire, and answers read from a raw stream (the PLC tests' independent peer)."""

from __future__ import annotations

import asyncio
import struct


def frame(tid: int, pdu: bytes, *, protocol: int = 0, length: int | None = None, unit: int = 1) -> bytes:
    """An MBAP frame: transaction id, protocol id, length (unit id and PDU unless given), unit id, the PDU."""
    return struct.pack(">HHHB", tid, protocol, len(pdu) + 1 if length is None else length, unit) + pdu


def fc3(tid: int, address: int, count: int) -> bytes:
    return frame(tid, struct.pack(">BHH", 3, address, count))


def fc6(tid: int, address: int, value: int) -> bytes:
    return frame(tid, struct.pack(">BHH", 6, address, value))


def fc16(tid: int, address: int, values: list[int]) -> bytes:
    return frame(tid, struct.pack(f">BHHB{len(values)}H", 16, address, len(values), 2 * len(values), *values))


async def read_answers(reader: asyncio.StreamReader, n: int, timeout_s: float = 5.0) -> list[tuple[int, bytes]]:
    """``n`` answers as (transaction id, PDU), in the order they came."""
    out = []
    for _ in range(n):
        head = await asyncio.wait_for(reader.readexactly(6), timeout_s)
        tid, protocol, length = struct.unpack(">HHH", head)
        assert protocol == 0
        body = await asyncio.wait_for(reader.readexactly(length), timeout_s)
        out.append((tid, body[1:]))
    return out
