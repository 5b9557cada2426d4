"""Test support for the PLC interface: an in-memory cell behind CellFacade, and a PLC client.

The PLC side uses pymodbus's own AsyncModbusTcpClient and its convert_to/from_registers for the
32-bit values, so the server's codec is checked against an independent implementation.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pymodbus.client import AsyncModbusTcpClient

from cellctl.cell.tags import CycleStep, PackMLCommand, PackMLState, UnitMode
from cellctl.config.plc import PlcConfig
from cellctl.plc import PlcServer
from cellctl.plc.facade import (
    CellStatus,
    CommandReply,
    CycleAcceptance,
    CycleOutcome,
    PlcErrorCode,
)
from cellctl.plc.handshake import MEASURED_REGISTERS
from cellctl.plc.register_map import CELL_BLOCK, PLC_BLOCK, RegType, register

ERR_NOT_READY = int(PlcErrorCode.NOT_READY)
ERR_UNKNOWN_RECIPE = int(PlcErrorCode.UNKNOWN_RECIPE)
ERR_INSTALL_FAILED = 1301  # a cell alarm id (alignment failed)


class MemoryCell:
    """A CellFacade over a tiny PackML subset; cycles run in their own task with seeded results.

    Refusals are stored as their id's outcome, as the facade's contract asks (``store_refusals``
    False plays a facade that does not, to show the interface's own memory of them).
    """

    TRANSITIONS = {
        (PackMLState.IDLE, PackMLCommand.STOP): PackMLState.STOPPED,
        (PackMLState.STOPPED, PackMLCommand.RESET): PackMLState.IDLE,
        (PackMLState.IDLE, PackMLCommand.ABORT): PackMLState.ABORTED,
        (PackMLState.STOPPED, PackMLCommand.ABORT): PackMLState.ABORTED,
        (PackMLState.ABORTED, PackMLCommand.CLEAR): PackMLState.STOPPED,
    }

    def __init__(self, *, seed: int = 20261122, cycle_s: float = 0.02,
                 recipes: frozenset[int] = frozenset({1, 2, 3}), failing_ids: frozenset[int] = frozenset(),
                 gate: asyncio.Event | None = None, store_refusals: bool = True) -> None:
        self.state = PackMLState.IDLE
        self.mode = UnitMode.PRODUCTION
        self.step = CycleStep.NONE
        self.stop_reason = 0
        self.seed = seed
        self.cycle_s = cycle_s
        self.recipes = recipes
        self.failing_ids = failing_ids
        self.gate = gate
        self.store_refusals = store_refusals
        self.refused: list[int] = []
        self.started: list[int] = []
        self.outcomes: dict[int, CycleOutcome] = {}
        self.running: dict[int, asyncio.Task[None]] = {}
        self.link_events: list[tuple[str, float]] = []
        self.commands: list[PackMLCommand] = []
        self.status_raises = False

    def status(self) -> CellStatus:
        if self.status_raises:
            raise RuntimeError("orchestrator not answering")
        return CellStatus(self.state, self.mode, self.step, self.stop_reason,
                          ready_for_cycle=self.state is PackMLState.IDLE and not self.running)

    async def start_cycle(self, req_id: int, recipe_id: int, part_id: int) -> CycleAcceptance:
        if req_id in self.outcomes or req_id in self.running:
            return CycleAcceptance(True)  # idempotent per id
        if recipe_id not in self.recipes:
            return self._refuse(req_id, recipe_id, part_id, ERR_UNKNOWN_RECIPE, f"unknown recipe {recipe_id}")
        if self.state is not PackMLState.IDLE or self.running:
            return self._refuse(req_id, recipe_id, part_id, ERR_NOT_READY, f"state {self.state.name}")
        self.started.append(req_id)
        self.state = PackMLState.EXECUTE
        self.running[req_id] = asyncio.create_task(self._run(req_id, recipe_id, part_id))
        return CycleAcceptance(True)

    def _refuse(self, req_id: int, recipe_id: int, part_id: int, code: int, reason: str) -> CycleAcceptance:
        self.refused.append(req_id)
        if self.store_refusals:
            self.outcomes[req_id] = CycleOutcome(
                req_id=req_id, recipe_id=recipe_id, part_id=part_id, ok=False, error_code=code,
                dx_mm=0.0, dy_mm=0.0, dz_mm=0.0, drx_rad=0.0, dry_rad=0.0, drz_rad=0.0, cycle_time_s=0.0)
        return CycleAcceptance(False, code, reason)

    async def _run(self, req_id: int, recipe_id: int, part_id: int) -> None:
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        for step in (CycleStep.CALIBRATE, CycleStep.ALIGN, CycleStep.SHOOT, CycleStep.COMPENSATE,
                     CycleStep.INSTALL, CycleStep.INSPECT):
            self.step = step
            if step is CycleStep.INSTALL and self.gate is not None:
                await self.gate.wait()  # held at INSTALL, where a test can see it however slowly it polls
            await asyncio.sleep(self.cycle_s / 6)
        rng = np.random.default_rng([self.seed, req_id])
        d_mm = rng.uniform(-8.0, 8.0, 3)
        d_rad = rng.uniform(-0.03, 0.03, 3)
        ok = req_id not in self.failing_ids
        measured = tuple(float(v) for v in rng.uniform(-0.4, 0.4, 6)) if ok else None
        self.outcomes[req_id] = CycleOutcome(
            req_id=req_id, recipe_id=recipe_id, part_id=part_id, ok=ok,
            error_code=0 if ok else ERR_INSTALL_FAILED,
            dx_mm=float(d_mm[0]), dy_mm=float(d_mm[1]), dz_mm=float(d_mm[2]),
            drx_rad=float(d_rad[0]), dry_rad=float(d_rad[1]), drz_rad=float(d_rad[2]),
            cycle_time_s=loop.time() - t0 + 12.0,
            measured=measured, measured_ok=None if measured is None else True,  # type: ignore[arg-type]
        )
        self.step = CycleStep.NONE
        self.state = PackMLState.IDLE
        del self.running[req_id]

    async def result_of(self, req_id: int) -> CycleOutcome | None:
        return self.outcomes.get(req_id)

    async def command(self, command: PackMLCommand) -> CommandReply:
        self.commands.append(command)
        nxt = self.TRANSITIONS.get((self.state, command))
        if nxt is None:
            return CommandReply.INVALID_IN_STATE
        self.state = nxt
        return CommandReply.ACCEPTED

    async def change_mode(self, mode: UnitMode) -> CommandReply:
        if self.state not in (PackMLState.STOPPED, PackMLState.IDLE, PackMLState.ABORTED):
            return CommandReply.INVALID_IN_STATE
        self.mode = mode
        return CommandReply.ACCEPTED

    def plc_link_lost(self, silent_for_s: float) -> None:
        self.link_events.append(("lost", silent_for_s))

    def plc_link_restored(self) -> None:
        self.link_events.append(("restored", 0.0))

    async def drain(self, timeout_s: float = 5.0) -> None:
        """Let running cycles finish; cancel those still held (a failed test never set its gate)."""
        tasks = list(self.running.values())
        if not tasks:
            return
        _, pending = await asyncio.wait(tasks, timeout=timeout_s)
        for task in pending:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


def plc_config(**overrides: Any) -> PlcConfig:
    base: dict[str, Any] = dict(host="127.0.0.1", port=0, unit_id=1, heartbeat_timeout_s=1.0,
                                cell_heartbeat_period_s=0.05, scan_period_s=0.005, facade_timeout_s=1.0,
                                cycle_result_timeout_s=5.0)
    base.update(overrides)
    return PlcConfig(**base)


@dataclass
class PlcClient:
    """The line PLC, as a pymodbus client that knows the register map's addresses and types."""

    client: AsyncModbusTcpClient
    word_order: str
    unit_id: int = 1
    heartbeat: int = 0
    _beat_task: asyncio.Task[None] | None = field(default=None, repr=False)
    _beat_stop: asyncio.Event = field(default_factory=asyncio.Event, repr=False)

    def _convert(self, reg_type: RegType) -> Any:
        dt = self.client.DATATYPE
        return {RegType.UINT16: dt.UINT16, RegType.INT16: dt.INT16, RegType.UINT32: dt.UINT32,
                RegType.FLOAT32: dt.FLOAT32}[reg_type]

    def to_registers(self, name: str, value: int | float) -> list[int]:
        reg = register(name)
        return self.client.convert_to_registers(value, self._convert(reg.type), word_order=self.word_order)

    async def read_cell(self, word_order: str | None = None) -> dict[str, Any]:
        """The whole cell block in one FC3 read, decoded with pymodbus's converters."""
        rr = await self.client.read_holding_registers(CELL_BLOCK.start, count=CELL_BLOCK.size,
                                                      device_id=self.unit_id)
        assert not rr.isError(), f"reading the cell block failed: {rr}"
        order = word_order or self.word_order
        out: dict[str, Any] = {}
        for reg in CELL_BLOCK.registers:
            off = reg.address - CELL_BLOCK.start
            out[reg.name] = self.client.convert_from_registers(
                rr.registers[off:off + reg.words], self._convert(reg.type), word_order=order)
            for bit in reg.bits:
                out[bit.name] = bool(out[reg.name] >> bit.index & 1)
        return out

    async def read_plc_block(self) -> list[int]:
        rr = await self.client.read_holding_registers(PLC_BLOCK.start, count=PLC_BLOCK.size,
                                                      device_id=self.unit_id)
        assert not rr.isError()
        return list(rr.registers)

    async def write(self, **values: int | float) -> None:
        """Write PLC-block registers; contiguous names go in one FC16 request."""
        regs = sorted((register(n) for n in values), key=lambda r: r.address)
        words: list[int] = []
        for i, reg in enumerate(regs):
            assert i == 0 or reg.address == regs[i - 1].end, "write contiguous registers together"
            words += self.to_registers(reg.name, values[reg.name])
        wr = await self.client.write_registers(regs[0].address, words, device_id=self.unit_id)
        assert not wr.isError(), f"PLC write failed: {wr}"

    async def wait_cell(self, predicate: Callable[[dict[str, Any]], bool], what: str,
                        timeout_s: float = 5.0) -> dict[str, Any]:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while True:
            cell = await self.read_cell()
            if predicate(cell):
                return cell
            if loop.time() > deadline:
                raise AssertionError(f"timed out waiting for {what}; cell block: {cell}")
            await asyncio.sleep(0.003)

    async def run_cycle(self, req_id: int, recipe_id: int, part_id: int, *, timeout_s: float = 5.0) -> dict[str, Any]:
        """The PLC's side of the four-way handshake; returns the cell block as read at done."""
        await self.write(recipe_id=recipe_id, part_id=part_id, cycle_req_id=req_id, cycle_request=1)
        done = await self.wait_cell(lambda c: c["done"] and c["cycle_ack_id"] == req_id,
                                    f"done for cycle {req_id}", timeout_s)
        await self.write(cycle_request=0)
        await self.wait_cell(lambda c: not c["done"] and not c["busy"], f"done cleared after {req_id}")
        return done

    async def command(self, cmd: int, *, settle_timeout_s: float = 10.0) -> dict[str, Any]:
        """The PLC's side of the command handshake; returns the acked cell block once the acting state
        the command started (if any) has passed."""
        await self.write(cntrl_cmd=int(cmd), cmd_change_request=1)
        ack = await self.wait_cell(lambda c: c["cmd_ack"] == 1 and c["cmd_ack_cmd"] == int(cmd), f"ack of command {cmd}")
        await self.write(cntrl_cmd=0, cmd_change_request=0)
        await self.wait_cell(lambda c: c["cmd_ack"] == 0, f"ack of command {cmd} cleared")
        acting = {s for s in PackMLState if s.name.endswith("ING")}
        await self.wait_cell(lambda c: PackMLState(c["state_current"]) not in acting, "a settled state", settle_timeout_s)
        return ack

    async def _beat(self, period_s: float, stop: asyncio.Event) -> None:
        while not stop.is_set():
            self.heartbeat = (self.heartbeat + 1) & 0xFFFF
            await self.write(plc_heartbeat=self.heartbeat)
            await asyncio.sleep(period_s)

    def start_heartbeat(self, period_s: float) -> None:
        self._beat_stop = asyncio.Event()
        self._beat_task = asyncio.create_task(self._beat(period_s, self._beat_stop))

    async def stop_heartbeat(self) -> None:
        """Stop beating. The flag ends the loop even when the cancel is lost: Python 3.11's
        asyncio.wait_for (inside pymodbus's request) can swallow a cancel that meets its answer,
        which once left this waiting for ever."""
        if self._beat_task is not None:
            self._beat_stop.set()
            self._beat_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await asyncio.wait_for(asyncio.shield(self._beat_task), 10.0)
            self._beat_task = None


@contextlib.asynccontextmanager
async def running_cell(cell: MemoryCell, **config: Any) -> AsyncIterator[tuple[PlcServer, PlcClient]]:
    """A started PlcServer on an ephemeral loopback port and a connected PLC client."""
    cfg = plc_config(**config)
    server = PlcServer(cfg, cell)
    await server.start()
    client = AsyncModbusTcpClient("127.0.0.1", port=server.port, timeout=2, retries=1)
    plc = PlcClient(client, cfg.float_word_order, unit_id=cfg.unit_id or 1)
    try:
        assert await client.connect(), "PLC client could not connect"
        yield server, plc
    finally:
        await plc.stop_heartbeat()
        client.close()
        await server.stop()
        await cell.drain()


def float32(x: float) -> float:
    """What a float32 register carries for x."""
    return float(np.float32(x))


def expected_wire(o: CycleOutcome) -> dict[str, float | int]:
    return {
        "dx_mm": float32(o.dx_mm), "dy_mm": float32(o.dy_mm), "dz_mm": float32(o.dz_mm),
        "drx_deg": float32(math.degrees(o.drx_rad)), "dry_deg": float32(math.degrees(o.dry_rad)),
        "drz_deg": float32(math.degrees(o.drz_rad)), "cycle_time_ms": round(o.cycle_time_s * 1000),
        "result_part_id": o.part_id, "result_recipe_id": o.recipe_id, "error_code": o.error_code,
        "inspection_status": o.inspection_status,
        **{name: float32(v) for name, v in zip(MEASURED_REGISTERS, o.measured or (0.0,) * 6)},
    }
