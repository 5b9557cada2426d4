"""Both PLC examples, driven through error_code 903 by the served simulated cell, end with the cell's real result.

docs/plc_register_map.md, Codes: 901-904 are "Stored: no", not results: "repeating that id asks the cell again".
The line's ordinary way to a 903: the PLC's request waits behind a cycle started over REST, the operator holds
the cell for longer than [plc] cycle_result_timeout_s (here 1.5 s; 900 s by default), then Unholds and the
queued cycle installs its glass. examples/plc_client.py (run as the README gives it) and examples/plc_handshake.st
(run by tests/plc/st_interpreter.py, the file's own text, over pymodbus) must then report that cycle's result,
as the cell's record over REST has it, and the .st must release the car body only after it.
"""

from __future__ import annotations

import asyncio
import contextlib
import re
import sys
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any

import httpx
import pytest
from pymodbus.client import AsyncModbusTcpClient
from service_test_support import AUTH, api_client, running_service, sim_config, slow_moves, to_execute
from st_interpreter import Program

from cellctl.service.compose import Service

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "plc_client.py"
ST = REPO / "examples" / "plc_handshake.st"
SLOW = 300.0  # the REST cycle ahead moves this much slower: it still runs when the PLC's request comes
pytestmark = pytest.mark.timeout(240)


def _config() -> Any:
    return sim_config(plc={"port": 0, "scan_period_s": 0.005, "facade_timeout_s": 0.5, "cycle_result_timeout_s": 1.5})


async def _until(what: str, check: Callable[[], Awaitable[Any]], timeout_s: float) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if value := await check():
            return value
        await asyncio.sleep(0.05)
    raise AssertionError(f"no {what} within {timeout_s:g} s")


async def _cycle_of(client: httpx.AsyncClient, source: str, key: str) -> dict[str, Any] | None:
    cycles = (await client.get("/cycles", params={"limit": 20})).json()
    return next((c for c in cycles if c["source"] == source and c["idempotency_key"] == key), None)


async def _state(client: httpx.AsyncClient) -> str:
    return str((await client.get("/status")).json()["state"])


@contextlib.asynccontextmanager
async def _cell_with_a_rest_cycle_ahead(tmp_path: Path) -> AsyncIterator[tuple[Service, httpx.AsyncClient]]:
    """The served cell in Execute, running a slow REST cycle (the PLC's request will queue behind it)."""
    async with running_service(tmp_path, _config()) as service, api_client(service) as client:
        await to_execute(client)
        slow_moves(service, SLOW)
        r = await client.post("/cycle", json={"recipe": "side-window", "part_id": "REST-1"},
                              headers={**AUTH, "Idempotency-Key": "rest-ahead"})
        assert r.status_code in (200, 201, 202), r.text

        async def rest_running() -> bool:
            cycles = (await client.get("/cycles", params={"limit": 5})).json()
            return any(c["idempotency_key"] == "rest-ahead" and c["state"] == "running" for c in cycles)

        await _until("running REST cycle", rest_running, 30)
        yield service, client


async def _hold_past_the_result_timeout(client: httpx.AsyncClient, plc_key: str) -> None:
    """The PLC's request queued behind the REST cycle: Hold (the REST cycle stops, the queue waits for Unhold)."""
    async def queued() -> bool:
        rec = await _cycle_of(client, "plc", plc_key)
        return rec is not None and rec["state"] == "queued"

    await _until(f"PLC request {plc_key} queued", queued, 30)
    assert (await client.post("/commands/hold", headers=AUTH)).status_code == 200

    async def held() -> bool:
        return await _state(client) == "HELD"

    await _until("Held", held, 60)


async def _unhold(service: Service, client: httpx.AsyncClient) -> None:
    slow_moves(service, 1 / SLOW)
    assert (await client.post("/commands/unhold", headers=AUTH)).status_code == 200


async def test_the_python_example_asks_again_after_903_and_prints_the_cells_result(tmp_path: Path) -> None:
    async with _cell_with_a_rest_cycle_ahead(tmp_path) as (service, client):
        proc = await asyncio.create_subprocess_exec(
            sys.executable, str(EXAMPLE), "--port", str(service.plc_server.port), "--part", "4711",  # type: ignore[attr-defined]
            "--car-body", "30117", "--req-id", "9300", "--heartbeat-period", "0.2", "--cycle-timeout", "60",
            cwd=tmp_path, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT,
        )  # fmt: skip
        lines: list[str] = []

        async def read() -> None:
            assert proc.stdout is not None
            async for raw in proc.stdout:
                lines.append(raw.decode().rstrip())

        reader = asyncio.create_task(read())
        try:
            await _hold_past_the_result_timeout(client, "9300")

            async def timed_out() -> bool:
                return any("903" in line for line in lines) or proc.returncode is not None

            await _until("903 seen by the example", timed_out, 30)
            await _unhold(service, client)
            await asyncio.wait_for(proc.wait(), 120)
            await reader
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()
        text = "\n".join(lines)
        record = await _cycle_of(client, "plc", "9300")
        assert record is not None and record["state"] == "done" and record["part_ok"] is True, (record, text)
        assert record["car_id"] == "30117", record  # --car-body reached the cell (registers 11-12)
        assert re.search(r"cycle_req_id 9300: error_code 903 \(result_timeout\) is no result; asking the cell "
                         r"again with the same id", text), text
        assert "NOK" not in text, text
        verdict = re.search(r"cycle_req_id 9300 part 4711: OK.*correction ([-+.\d]+) ([-+.\d]+) ([-+.\d]+) mm", text)
        assert verdict is not None, text
        for printed, stored in zip(verdict.groups(), record["result"]["correction_mm"], strict=True):
            assert float(printed) == pytest.approx(stored, abs=6e-4), (verdict.group(0), record["result"])
        assert proc.returncode == 0, text


def _alive(task: asyncio.Task[None]) -> None:
    """Raise the PLC task's own error, if it ended."""
    if task.done():
        task.result()
        raise AssertionError("the PLC task ended")


async def _scan(prog: Program, line: Any, modbus: AsyncModbusTcpClient) -> None:
    """One PLC task cycle as the .st's header asks: FC3 100..163, the program, FC16 0..12."""
    rr = await modbus.read_holding_registers(100, count=64, device_id=1)
    assert not rr.isError(), rr
    line.CellBlock[:] = rr.registers
    prog.run(line)
    wr = await modbus.write_registers(0, list(line.PlcBlock), device_id=1)
    assert not wr.isError(), wr


async def test_the_structured_text_asks_again_after_903_and_releases_after_the_real_result(tmp_path: Path) -> None:
    prog = Program(ST.read_text(), time.monotonic)
    line = prog.instance("PLC_CellLine")
    line.Cell.NextReqId = 9400
    done_events: list[dict[str, Any]] = []
    releases: list[int] = []
    asked_again: list[int] = []
    async with _cell_with_a_rest_cycle_ahead(tmp_path) as (service, client):
        modbus = AsyncModbusTcpClient("127.0.0.1", port=service.plc_server.port, timeout=2, retries=1)  # type: ignore[attr-defined]
        assert await modbus.connect()
        stop = asyncio.Event()

        async def plc_task() -> None:
            while not stop.is_set():
                await _scan(prog, line, modbus)
                c = line.Cell
                if c.CycleDone:
                    done_events.append({"req": c.ResultReqId, "ok": c.ResultOk, "code": c.ErrorCode,
                                        "mm": list(c.CorrectionMm), "car": c.ResultCarBodyId})
                if getattr(c, "AskedAgain", False) and not asked_again:
                    asked_again.append(c.AskedAgainCode)
                if line.ReleaseCarBody:
                    releases.append(len(done_events))
                await asyncio.sleep(0.02)

        task = asyncio.create_task(plc_task())
        try:
            line.WindowSerial, line.CarBodySerial, line.CarBodyInPlace = 5001, 777, True
            await _hold_past_the_result_timeout(client, "9400")

            async def answered() -> bool:
                _alive(task)
                return bool(asked_again or done_events)

            await _until("the 903 handled by the .st", answered, 30)
            await _unhold(service, client)

            async def released() -> bool:
                _alive(task)
                return bool(releases)

            await _until("ReleaseCarBody", released, 120)
        finally:
            stop.set()
            await task
            modbus.close()
        record = await _cycle_of(client, "plc", "9400")
    assert record is not None and record["state"] == "done" and record["part_ok"] is True, record
    assert done_events and done_events[0]["req"] == 9400, done_events
    first = done_events[0]
    assert first["ok"] and first["code"] == 0, (
        f"the .st took {first} as the result of 9400 while the cell installed it OK (cycle {record['id']})")
    assert asked_again == [903], asked_again
    assert first["car"] == 777 and record["car_id"] == "777"
    assert first["mm"] == pytest.approx(record["result"]["correction_mm"], abs=1e-4)
    assert releases == [1], "the car body moved on once, after the real result"
    assert line.WindowInstalled and not line.WindowNok and not line.CellAskedAgain
    assert not line.Cell.InFlight and not line.Cell.Fault
