"""The line PLC's side of cellctl's Modbus TCP interface, short: heartbeat, PackML commands to Execute,
then cycles by the four-way handshake, printing each result. The same handshake as the IEC 61131-3
program beside it (examples/plc_handshake.st); addresses, types and bits are docs/plc_register_map.md's.

    python examples/plc_client.py --host 127.0.0.1 --port 5020 --recipe 1 --part 4711 --car-body 30117 --cycles 2

The cell is the Modbus TCP server; this is the client, as the PLC is. It needs only pymodbus
(``pip install pymodbus``). Each cycle gets a new nonzero ``cycle_req_id`` (a real PLC keeps its
counter in retained memory: the cell never runs an id twice, and answers a repeated id with that
id's stored result and ``replayed`` = 1). A ``done`` with ``error_code`` 901-904 (the interface's own codes)
is no result: the cycle may still be queued or running, so the client asks again with the same id until the
real result comes. Exit status 0 when every cycle ended ``ok``.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import struct
import sys
import time
from typing import Any

from pymodbus.client import AsyncModbusTcpClient

# -- the register map (docs/plc_register_map.md, map version 1.x) ---------------------------------
MAP_MAJOR = 1
PLC_HEARTBEAT, CNTRL_CMD, CMD_CHANGE_REQUEST = 0, 1, 2  # PLC block, 0-31: written by the PLC
RECIPE_ID, PART_ID, CYCLE_REQ_ID, CYCLE_REQUEST, CAR_BODY_ID = 5, 6, 8, 10, 11  # part, req, car body: uint32
CELL_START, CELL_SIZE = 100, 64  # cell block, 100-163: written by the cell, read in one FC3 request
CELL_UINT16 = {
    "map_version_major": 100, "cell_heartbeat": 102, "state_current": 103, "cycle_step": 105, "stop_reason_id": 106,
    "cycle_flags": 107, "result_recipe_id": 114, "error_code": 115, "cmd_ack": 130, "cmd_ack_cmd": 131,
    "cmd_result": 132, "inspection_status": 137, "interlock_alarm_id": 152,
}  # fmt: skip
CELL_UINT32 = {"cycle_ack_id": 108, "result_req_id": 110, "result_part_id": 112, "cycle_time_ms": 128,
               "result_car_body_id": 150}
CELL_FLOAT32 = {
    "dx_mm": 116, "dy_mm": 118, "dz_mm": 120, "drx_deg": 122, "dry_deg": 124, "drz_deg": 126,
    "meas_dx_mm": 138, "meas_dy_mm": 140, "meas_dz_mm": 142, "meas_drx_deg": 144, "meas_dry_deg": 146, "meas_drz_deg": 148,
}  # fmt: skip
FLAG_BITS = {"ready": 0, "busy": 1, "done": 2, "ok": 3, "nok": 4, "replayed": 5, "plc_heartbeat_ok": 6, "request_mismatch": 7,
             "install_started": 8, "robot_clear": 9}

# PackML (PackTags numbers): commands and states
RESET, START, UNHOLD, CLEAR = 1, 2, 5, 9
STOPPED, IDLE, EXECUTE, ABORTED, HELD = 2, 4, 6, 9, 11
ACTING = {1, 3, 7, 8, 10, 12, 13, 14, 15, 16}  # clearing, starting, stopping, ..., completing
TO_EXECUTE = {ABORTED: [CLEAR, RESET, START], STOPPED: [RESET, START], IDLE: [START], HELD: [UNHOLD], EXECUTE: []}
CMD_RESULTS = {0: "accepted", 1: "invalid in state", 2: "busy", 3: "bad parameter", 4: "no answer", 5: "blocked"}
# error_code values that are no result ("Stored: no"): the cycle may still be queued or running; ask the same id again
NOT_RESULTS = {901: "cycle_req_id_zero", 902: "cell_no_answer", 903: "result_timeout", 904: "cell_bad_answer"}


class HandshakeError(RuntimeError):
    """The cell did not answer a handshake as the register map says, in time."""


class Plc:
    """A PLC over Modbus TCP: the cell block read whole and decoded, PLC-block writes, the handshakes."""

    def __init__(self, client: AsyncModbusTcpClient, unit: int, word_order: str, timeout_s: float) -> None:
        self.client, self.unit, self.big = client, unit, word_order == "big"
        self.timeout_s = timeout_s
        self.heartbeat = 0

    def _u32(self, words: list[int]) -> int:
        hi, lo = words if self.big else words[::-1]
        return hi << 16 | lo

    def _words(self, value: int) -> list[int]:
        hi, lo = value >> 16 & 0xFFFF, value & 0xFFFF
        return [hi, lo] if self.big else [lo, hi]

    async def read_cell(self) -> dict[str, Any]:
        """The cell block in one FC3 read, as named values (flags as booleans)."""
        rr = await self.client.read_holding_registers(CELL_START, count=CELL_SIZE, device_id=self.unit)
        if rr.isError():
            raise HandshakeError(f"reading the cell block failed: {rr}")
        regs = rr.registers

        def at(address: int, words: int = 1) -> list[int]:
            return regs[address - CELL_START:address - CELL_START + words]

        cell: dict[str, Any] = {name: at(a)[0] for name, a in CELL_UINT16.items()}
        cell.update({name: self._u32(at(a, 2)) for name, a in CELL_UINT32.items()})
        cell.update({name: struct.unpack(">f", struct.pack(">I", self._u32(at(a, 2))))[0] for name, a in CELL_FLOAT32.items()})
        cell.update({name: bool(cell["cycle_flags"] >> bit & 1) for name, bit in FLAG_BITS.items()})
        return cell

    async def write(self, address: int, words: list[int]) -> None:
        """One FC16 write into the PLC block."""
        wr = await self.client.write_registers(address, words, device_id=self.unit)
        if wr.isError():
            raise HandshakeError(f"writing {address}: {wr}")

    async def wait(self, what: str, predicate: Any, timeout_s: float | None = None) -> dict[str, Any]:
        """Read the cell block until ``predicate(cell)`` holds."""
        deadline = time.monotonic() + (timeout_s or self.timeout_s)
        while True:
            cell = await self.read_cell()
            if predicate(cell):
                return cell
            if time.monotonic() > deadline:
                raise HandshakeError(f"no {what} within {timeout_s or self.timeout_s:g} s (state {cell['state_current']})")
            await asyncio.sleep(0.02)

    async def beat(self, period_s: float) -> None:
        """Change plc_heartbeat every ``period_s`` (at most heartbeat_timeout_s / 5), for as long as the PLC runs."""
        while True:
            self.heartbeat = (self.heartbeat + 1) & 0xFFFF
            await self.write(PLC_HEARTBEAT, [self.heartbeat])
            await asyncio.sleep(period_s)

    async def command(self, cmd: int) -> int:
        """The command handshake: cntrl_cmd with cmd_change_request = 1, wait cmd_ack, drop the request,
        wait cmd_ack = 0, then until the acting state the command started has passed. Returns cmd_result."""
        await self.write(CNTRL_CMD, [cmd, 1])
        ack = await self.wait(f"cmd_ack of command {cmd}", lambda c: c["cmd_ack"] == 1 and c["cmd_ack_cmd"] == cmd)
        await self.write(CNTRL_CMD, [0, 0])
        await self.wait("cmd_ack cleared", lambda c: c["cmd_ack"] == 0)
        await self.wait("a settled state", lambda c: c["state_current"] not in ACTING)
        return int(ack["cmd_result"])

    async def to_execute(self) -> None:
        """Clear, Reset, Start (or Unhold) as the state asks, each once the state before has settled."""
        cell = await self.wait("a settled state", lambda c: c["state_current"] not in ACTING)
        plan = TO_EXECUTE.get(cell["state_current"])
        if plan is None:
            raise HandshakeError(f"state {cell['state_current']}: bring the cell to Stopped, Idle or Aborted first")
        for cmd in plan:
            result = await self.command(cmd)
            if result != 0:
                cell = await self.read_cell()
                raise HandshakeError(f"command {cmd} answered {result} ({CMD_RESULTS.get(result, '?')}); interlock alarm "
                                     f"{cell['interlock_alarm_id']}, stop reason {cell['stop_reason_id']}")  # fmt: skip

    async def cycle(self, req_id: int, recipe_id: int, part_id: int, timeout_s: float,
                    car_body_id: int = 0) -> dict[str, Any]:
        """The four-way cycle handshake; returns the cell block as read at the ``done`` with this id's result.
        A ``done`` with error_code 901-904 is none: drop the request, wait until ``done`` clears and ask again
        with the same id (busy while its cycle is queued or runs, at once replayed if it has ended). Never a
        new id for it: that would run a second cycle. ``timeout_s`` is for each asking, from request to done."""
        if not 0 < req_id <= 0xFFFFFFFF:
            raise HandshakeError(f"cycle_req_id {req_id}: give each cycle a nonzero uint32 id")
        await self.wait("ready", lambda c: c["ready"])
        while True:
            # recipe_id (5), part_id (6-7), cycle_req_id (8-9), cycle_request (10) and car_body_id (11-12) are
            # contiguous: one FC16 write (car_body_id 0 when none is given, never what an earlier client left)
            await self.write(RECIPE_ID, [recipe_id, *self._words(part_id), *self._words(req_id), 1,
                                         *self._words(car_body_id)])
            done = await self.wait(f"done of cycle {req_id}", lambda c: c["done"] and c["cycle_ack_id"] == req_id,
                                   timeout_s)
            await self.write(CYCLE_REQUEST, [0])
            await self.wait("done cleared", lambda c: not c["done"])
            code = done["error_code"]
            if code not in NOT_RESULTS:
                return done
            print(f"warning: cycle_req_id {req_id}: error_code {code} ({NOT_RESULTS[code]}) is no result; "
                  "asking the cell again with the same id", file=sys.stderr, flush=True)


def report(done: dict[str, Any]) -> str:
    """One line for a result."""
    verdict = "OK" if done["ok"] else f"NOK error_code {done['error_code']}"
    text = (f"cycle_req_id {done['result_req_id']} part {done['result_part_id']}: {verdict}"
            f"{' (replayed)' if done['replayed'] else ''}, {done['cycle_time_ms'] / 1000:.1f} s; correction "
            f"{done['dx_mm']:+.3f} {done['dy_mm']:+.3f} {done['dz_mm']:+.3f} mm")  # fmt: skip
    if done["inspection_status"]:
        text += (f"; measured {done['meas_dx_mm']:+.3f} {done['meas_dy_mm']:+.3f} {done['meas_dz_mm']:+.3f} mm "
                 f"({'within' if done['inspection_status'] == 1 else 'outside'} the tolerance)")  # fmt: skip
    if done["result_car_body_id"]:
        text += f"; car body {done['result_car_body_id']}"
    return text


async def main(args: argparse.Namespace) -> int:
    client = AsyncModbusTcpClient(args.host, port=args.port, timeout=2, retries=1)
    if not await client.connect():
        print(f"cannot connect to the cell's Modbus TCP server at {args.host}:{args.port}", file=sys.stderr)
        return 2
    plc = Plc(client, args.unit, args.word_order, args.timeout)
    beat = asyncio.create_task(plc.beat(args.heartbeat_period))
    try:
        cell = await plc.read_cell()
        if cell["map_version_major"] != MAP_MAJOR:
            raise HandshakeError(f"register map major version {cell['map_version_major']}, this PLC knows {MAP_MAJOR}")
        await plc.wait("plc_heartbeat_ok", lambda c: c["plc_heartbeat_ok"])
        await plc.to_execute()
        print(f"cell in Execute (cell_heartbeat {cell['cell_heartbeat']})", flush=True)
        req_id = args.req_id or int(time.time()) & 0x7FFFFFFF  # new and nonzero; a PLC keeps a retained counter
        all_ok = True
        for n in range(args.cycles):
            car_body = args.car_body + n if args.car_body else 0
            done = await plc.cycle(req_id + n, args.recipe, args.part + n, args.cycle_timeout, car_body)
            print(report(done), flush=True)
            all_ok = all_ok and bool(done["ok"])
        return 0 if all_ok else 1
    except HandshakeError as err:
        print(f"handshake failed: {err}", file=sys.stderr)
        return 1
    finally:
        beat.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await beat
        client.close()


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=5020, help="[plc] port (502 on a line)")
    p.add_argument("--unit", type=int, default=1, help="[plc] unit_id")
    p.add_argument("--word-order", choices=("big", "little"), default="big", help="[plc] float_word_order")
    p.add_argument("--recipe", type=int, default=1, help="an id of the cell's [[process.recipes]]")
    p.add_argument("--part", type=int, default=1, help="part_id of the first cycle (the next ones count up)")
    p.add_argument("--car-body", type=int, default=0,
                   help="car_body_id of the first cycle (the next ones count up); 0: none given")
    p.add_argument("--cycles", type=int, default=1)
    p.add_argument("--req-id", type=int, default=0, help="cycle_req_id of the first cycle (default: from the clock)")
    p.add_argument("--heartbeat-period", type=float, default=0.5, help="s; at most heartbeat_timeout_s / 5")
    p.add_argument("--timeout", type=float, default=15.0, help="s for each command handshake step")
    p.add_argument("--cycle-timeout", type=float, default=300.0,
                   help="s from the request (and from each asking again) to done")
    return p.parse_args(argv)


if __name__ == "__main__":
    sys.exit(asyncio.run(main(parse_args())))
