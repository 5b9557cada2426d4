"""Malformed Modbus TCP frames and function codes the register map does not serve (Modbus Application Protocol
v1.1b3, sec. 7): the exception's function code is the request's | 0x80; a quantity out of range is exception 3;
a function code the map does not serve (diagnostics, report server id, device identification, coils...) is
exception 1, as docs/plc_register_map.md says; a frame that cannot be Modbus TCP closes the connection.
Peers: raw sockets and pymodbus's client."""

from __future__ import annotations

import asyncio
import logging
import struct

import pytest
from modbus_wire import fc3, frame, read_answers
from plc_test_support import MemoryCell, running_cell

from cellctl.plc.register_doc import render_markdown
from cellctl.plc.register_map import CELL_BLOCK, MAP_VERSION


async def ask(port: int, request: bytes) -> bytes:
    """The PDU the server answers ``request`` with on a fresh connection."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(request)
        [(_tid, pdu)] = await read_answers(reader, 1)
        return pdu
    finally:
        writer.close()


QUANTITY_ERRORS = [
    ("FC3 quantity 0", struct.pack(">BHH", 3, 100, 0), 0x83),
    ("FC3 quantity 126", struct.pack(">BHH", 3, 0, 126), 0x83),
    ("FC3 short PDU", struct.pack(">BH", 3, 100), 0x83),
    ("FC16 quantity 0", struct.pack(">BHHB", 16, 20, 0, 0), 0x90),
    ("FC16 byte count mismatch", struct.pack(">BHHB", 16, 20, 2, 2) + b"\x00\x01", 0x90),
    ("FC23 read quantity 0", struct.pack(">BHHHHB", 23, 100, 0, 20, 1, 2) + b"\x00\x00", 0x97),
]
NOT_SERVED = [1, 2, 4, 5, 7, 8, 11, 12, 15, 17, 20, 21, 24, 43, 0x41, 0x64]


async def test_exceptions_carry_the_request_function_code_and_the_right_exception() -> None:
    async with running_cell(MemoryCell()) as (server, plc):
        for label, pdu, answer_fc in QUANTITY_ERRORS:
            assert await ask(server.port, frame(1, pdu)) == bytes([answer_fc, 3]), label
        for fc in NOT_SERVED:
            assert await ask(server.port, frame(2, bytes([fc, 0, 0, 0, 1]))) == bytes([fc | 0x80, 1]), fc
        assert await ask(server.port, frame(3, bytes([0x8F, 0, 0]))) == bytes([0x8F, 1])
        # the map's own exceptions are unchanged: into the cell block 2 (counted), another unit id 11
        assert await ask(server.port, frame(4, struct.pack(">BHHB", 16, CELL_BLOCK.start, 1, 2) + b"\x00\x05")) == b"\x90\x02"
        assert await ask(server.port, frame(5, struct.pack(">BHH", 3, CELL_BLOCK.start, 2), unit=7)) == b"\x83\x0b"
        assert server.refused_writes == 1
        rr = await plc.client.read_holding_registers(CELL_BLOCK.start, count=2, device_id=1)
        assert rr.registers == list(MAP_VERSION)
        assert (await plc.client.read_holding_registers(20, count=2, device_id=1)).registers == [0, 0]  # nothing written


async def test_diagnostics_identification_and_coils_get_exception_1_from_a_modbus_client() -> None:
    async with running_cell(MemoryCell()) as (_server, plc):
        client = plc.client
        replies = {
            "FC8 echo": await client.diag_read_bus_message_count(device_id=1),
            "FC7": await client.read_exception_status(device_id=1),
            "FC11": await client.diag_get_comm_event_counter(device_id=1),
            "FC17": await client.report_device_id(device_id=1),
            "FC43/14": await client.read_device_information(device_id=1),
            "FC1": await client.read_coils(0, count=1, device_id=1),
            "FC4": await client.read_input_registers(0, count=1, device_id=1),
        }
        for name, rr in replies.items():
            assert rr.isError() and rr.exception_code == 1, (name, rr)
        await plc.write(recipe_id=2)  # the connection is still served
        assert (await plc.read_plc_block())[5] == 2


@pytest.mark.parametrize("bad", ["protocol id 1", "MBAP length 0", "MBAP length 1", "MBAP length 255", "MBAP length 300"])
async def test_a_frame_that_is_not_modbus_tcp_closes_the_connection_after_the_frames_before_it(
        bad: str, caplog: pytest.LogCaptureFixture) -> None:
    read = struct.pack(">BHH", 3, 100, 2)
    wrong = {"protocol id 1": frame(9, read, protocol=1), "MBAP length 0": frame(9, b"", length=0),
             "MBAP length 1": frame(9, b"", length=1), "MBAP length 255": frame(9, read, length=255),
             "MBAP length 300": frame(9, read, length=300)}[bad]  # fmt: skip
    caplog.set_level(logging.WARNING)
    async with running_cell(MemoryCell()) as (server, plc):
        for _ in range(3):  # three connections from one peer: closed each, logged once
            reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
            try:
                writer.write(fc3(8, 100, 2) + wrong + fc3(10, 100, 2))
                [(tid, pdu)] = await read_answers(reader, 1)
                assert tid == 8 and pdu == struct.pack(">BB2H", 3, 4, *MAP_VERSION)
                assert await asyncio.wait_for(reader.read(100), 5.0) == b""  # closed, nothing more answered
            finally:
                writer.close()
        assert (await plc.client.read_holding_registers(100, count=2, device_id=1)).registers == list(MAP_VERSION)
    said = [r.getMessage() for r in caplog.records if "is not Modbus TCP" in r.getMessage()]
    assert len(said) == 1 and "127.0.0.1" in said[0], said


def test_the_register_map_says_which_function_codes_are_served_and_how_connections_are_kept() -> None:
    flat = " ".join(render_markdown().split())
    assert "read with FC3, write with FC16 (or FC6, FC22, FC23)" in flat
    assert "Every other function code (coils, input registers, diagnostics FC8, FC7, FC11, FC17, FC43) gets " \
           "exception code 1 (illegal function)" in flat
    assert "exception code 3 (illegal data value)" in flat and "`[plc] idle_timeout_s`" in flat
