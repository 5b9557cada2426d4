"""The line PLC as a benchmark plays it: Modbus TCP to the cell's server, the register map's cycle handshake.

It writes its whole PLC block at every step, as a PLC writes its output area each scan (the
heartbeat counting up), and reads the whole cell block; both through the register map's codec.
The handshake is the one `docs/plc_register_map.md` describes: recipe, part and a new
``cycle_req_id`` with ``cycle_request`` = 1, wait for ``done`` with that id, read the result, set
``cycle_request`` = 0, wait for ``done`` to clear.
"""

from __future__ import annotations

import asyncio
import time
from typing import Any

from pymodbus.client import AsyncModbusTcpClient

from cellctl.plc.codec import Value, WordOrder, decode_block, encode_block
from cellctl.plc.register_map import CELL_BLOCK, PLC_BLOCK

POLL_S = 0.005  # how often the PLC reads the cell block while it waits


class LinePlcError(RuntimeError):
    """The cell's Modbus server did not answer, or not in time."""


class LinePlc:
    """One PLC connection (``async with``); :meth:`cycle` runs one cycle handshake."""

    def __init__(self, host: str, port: int, word_order: WordOrder, unit_id: int = 1, *, timeout_s: float = 2.0) -> None:
        self._where = (host, port, timeout_s)
        self._client: AsyncModbusTcpClient | None = None
        self._order = word_order
        self._unit = unit_id
        self._out: dict[str, Value] = {r.name: 0 for r in PLC_BLOCK.registers}

    async def __aenter__(self) -> "LinePlc":
        host, port, timeout_s = self._where
        self._client = AsyncModbusTcpClient(host, port=port, timeout=timeout_s, retries=1)  # made on the running loop
        if not await self._client.connect():
            raise LinePlcError(f"no Modbus TCP server answers at {host}:{port}")
        await self._write()
        return self

    async def __aexit__(self, *exc: object) -> None:
        if self._client is not None:
            self._client.close()

    @property
    def client(self) -> AsyncModbusTcpClient:
        if self._client is None:
            raise LinePlcError("use the PLC inside `async with`")
        return self._client

    async def _write(self) -> None:
        self._out["plc_heartbeat"] = (int(self._out["plc_heartbeat"]) + 1) % 65536
        words = encode_block(PLC_BLOCK, self._out, self._order)
        reply = await self.client.write_registers(PLC_BLOCK.start, words, device_id=self._unit)
        if reply.isError():
            raise LinePlcError(f"writing the PLC block failed: {reply}")

    async def read_cell(self) -> dict[str, Any]:
        """The cell block, each flags word also as its named bits."""
        reply = await self.client.read_holding_registers(CELL_BLOCK.start, count=CELL_BLOCK.size, device_id=self._unit)
        if reply.isError():
            raise LinePlcError(f"reading the cell block failed: {reply}")
        cell: dict[str, Any] = decode_block(CELL_BLOCK, reply.registers, self._order)
        for reg in CELL_BLOCK.registers:
            for bit in reg.bits:
                cell[bit.name] = bool(int(cell[reg.name]) >> bit.index & 1)
        return cell

    async def _until(self, ready: Any, what: str, timeout_s: float) -> dict[str, Any]:
        deadline = time.monotonic() + timeout_s
        while True:
            await self._write()  # the heartbeat goes on while the PLC waits
            cell = await self.read_cell()
            if ready(cell):
                return cell
            if time.monotonic() > deadline:
                raise LinePlcError(f"{what}: not within {timeout_s:g} s")
            await asyncio.sleep(POLL_S)

    async def cycle(self, recipe_id: int, part_id: int, req_id: int, timeout_s: float) -> dict[str, Any]:
        """Request one cycle and return the cell block that carries its result (``ok``, ``nok``, ``error_code``, ...)."""
        self._out.update(recipe_id=recipe_id, part_id=part_id, cycle_req_id=req_id, cycle_request=1)
        result = await self._until(lambda c: c["done"] and c["cycle_ack_id"] == req_id, f"cycle {req_id}'s result", timeout_s)
        self._out["cycle_request"] = 0
        await self._until(lambda c: not c["done"], f"done cleared after cycle {req_id}", 10.0)
        return result
