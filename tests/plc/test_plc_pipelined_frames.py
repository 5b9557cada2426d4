"""Several Modbus TCP requests in one receive (a client with requests outstanding, or Nagle coalescing two writes):
every complete MBAP frame is served in order and answered with its transaction id; a partial frame waits for the
rest. Peers: raw sockets (the bytes on the wire) and pymodbus's client (the registers read back)."""

from __future__ import annotations

import asyncio
import struct

from modbus_wire import fc3, fc6, fc16, read_answers
from plc_test_support import MemoryCell, running_cell

from cellctl.plc.register_map import PLC_BLOCK

RESERVED = (20, 21)  # reserved PLC-block addresses: they keep what a client writes (docs/plc_register_map.md)


async def test_two_writes_in_one_segment_are_both_applied_and_answered() -> None:
    async with running_cell(MemoryCell()) as (server, plc):
        reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
        try:
            writer.write(fc6(11, RESERVED[0], 1111) + fc6(12, RESERVED[1], 2222))
            await writer.drain()
            answers = await read_answers(reader, 2)
            assert [tid for tid, _ in answers] == [11, 12]
            assert [pdu for _, pdu in answers] == [struct.pack(">BHH", 6, RESERVED[0], 1111),
                                                   struct.pack(">BHH", 6, RESERVED[1], 2222)]  # echoes, no exception
            rr = await plc.client.read_holding_registers(RESERVED[0], count=2, device_id=1)
            assert not rr.isError() and rr.registers == [1111, 2222]
        finally:
            writer.close()


async def test_ten_reads_in_one_segment_get_ten_answers_in_order() -> None:
    async with running_cell(MemoryCell()) as (server, plc):
        await plc.write(recipe_id=3, part_id=4)
        expected = (await plc.client.read_holding_registers(PLC_BLOCK.start, count=8, device_id=1)).registers
        reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
        try:
            writer.write(b"".join(fc3(100 + i, PLC_BLOCK.start, 8) for i in range(10)))
            answers = await read_answers(reader, 10)
            assert [tid for tid, _ in answers] == list(range(100, 110))
            for _, pdu in answers:
                assert pdu == struct.pack(">BB8H", 3, 16, *expected)
            writer.write(fc3(999, 5, 1))  # the connection goes on serving
            assert await read_answers(reader, 1) == [(999, struct.pack(">BBH", 3, 2, 3))]
        finally:
            writer.close()


async def test_a_write_then_a_read_in_one_segment_are_served_in_order() -> None:
    async with running_cell(MemoryCell()) as (server, _plc):
        reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
        try:
            writer.write(fc16(1, RESERVED[0], [7, 8]) + fc3(2, RESERVED[0], 2) + fc6(3, RESERVED[1], 9) + fc3(4, RESERVED[0], 2))
            answers = dict(await read_answers(reader, 4))
            assert answers[2] == struct.pack(">BB2H", 3, 4, 7, 8)  # the write before it was applied first
            assert answers[4] == struct.pack(">BB2H", 3, 4, 7, 9)
        finally:
            writer.close()


async def test_a_partial_frame_waits_for_the_rest_and_big_bursts_are_kept_whole() -> None:
    async with running_cell(MemoryCell()) as (server, plc):
        reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
        try:
            first, second, third = fc6(21, RESERVED[0], 5), fc6(22, RESERVED[1], 6), fc3(23, RESERVED[0], 2)
            writer.write(first[:5])
            await writer.drain()
            await asyncio.sleep(0.2)
            writer.write(first[5:] + second + third[:9])  # the rest of one, a whole one, the start of a third
            assert [tid for tid, _ in await read_answers(reader, 2)] == [21, 22]
            await asyncio.sleep(0.2)
            writer.write(third[9:])
            assert await read_answers(reader, 1) == [(23, struct.pack(">BB2H", 3, 4, 5, 6))]
            # 16 writes of the 19 reserved registers and 4 reads in one segment: 864 bytes (pymodbus alone dropped
            # all of a receive over 516 bytes)
            burst = [fc16(30 + k, PLC_BLOCK.start + 13, [k + 1] * 19) for k in range(16)]
            reads = [fc3(60 + k, PLC_BLOCK.start + 13, 19) for k in range(4)]
            writer.write(b"".join(burst) + b"".join(reads))
            answers = await read_answers(reader, 20)
            assert [tid for tid, _ in answers] == [*range(30, 46), *range(60, 64)]
            assert all(pdu == struct.pack(">BHH", 16, PLC_BLOCK.start + 13, 19) for _, pdu in answers[:16])
            assert all(pdu == struct.pack(">BB19H", 3, 38, *[16] * 19) for _, pdu in answers[16:])
            rr = await plc.client.read_holding_registers(PLC_BLOCK.start + 13, count=19, device_id=1)
            assert rr.registers == [16] * 19  # the last of the writes, applied in order
        finally:
            writer.close()
