"""A PLC-started cycle keeps the recipe_id the PLC sent: a repeated cycle_req_id answers that number in
``result_recipe_id`` (and no ``request_mismatch``) after a restart with [[process.recipes]] ids swapped or the recipe
renamed; a record made before the id was kept falls back to the name's current id.

Peers: pymodbus reads the PLC's registers (holding register 114 is ``result_recipe_id``, docs/plc_register_map.md);
an independent sqlite3 connection reads what the store keeps.
"""

from __future__ import annotations

import hashlib
import json
import sqlite3
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

from plc_test_support import PlcClient
from pymodbus.client import AsyncModbusTcpClient
from service_test_support import AUTH, ROOT, api_client, running_service, to_execute

from cellctl.config import CellConfig, parse_config

Recipes = list[dict[str, Any]]


def _config(recipes: Recipes) -> CellConfig:
    """config/sim.toml (oracle calibration, OPC UA off, PLC and API on port 0) with these recipes."""
    data = tomllib.loads((ROOT / "config" / "sim.toml").read_text())
    data["calibration"] = {"source": "oracle"}
    data["opcua"]["enabled"] = False
    data["plc"] |= {"port": 0, "scan_period_s": 0.005}
    data["api"]["port"] = 0
    data["sim"]["seed"] = 3
    data["process"]["recipes"] = recipes
    return parse_config(data, "sim.toml (test)")


def _sim_recipes() -> tuple[dict[str, Any], dict[str, Any]]:
    side, door = tomllib.loads((ROOT / "config" / "sim.toml").read_text())["process"]["recipes"]
    assert (side["id"], side["name"], door["id"], door["name"]) == (1, "side-window", 2, "door-window")
    return side, door


async def _plc_cycle(tmp_path: Path, recipes: Recipes, req_id: int, *, replay: bool,
                     recipe_ids: tuple[int, ...] = (2,)) -> tuple[list[tuple[dict[str, Any], int]], Path]:
    """Start the service on ``tmp_path`` with ``recipes``; the PLC asks for cycle ``req_id`` (part 77) once per
    recipe_id of ``recipe_ids``. Per request the cell's block at done and holding register 114 read raw; the store's
    file."""
    answers: list[tuple[dict[str, Any], int]] = []
    async with running_service(tmp_path, _config(recipes)) as service, api_client(service) as client:
        await to_execute(client)
        port = service.plc_server.port  # type: ignore[attr-defined]
        plc = PlcClient(AsyncModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=1),
                        service.config.plc.float_word_order, unit_id=service.config.plc.unit_id or 1)
        assert await plc.client.connect()
        try:
            for n, recipe_id in enumerate(recipe_ids):
                await plc.write(recipe_id=recipe_id, part_id=77, cycle_req_id=req_id, cycle_request=1)
                done = await plc.wait_cell(lambda c: c["done"] and c["cycle_ack_id"] == req_id, f"cycle {req_id}",
                                           30.0 if replay or n else 120.0)
                rr = await plc.client.read_holding_registers(114, count=1, device_id=plc.unit_id)
                assert not rr.isError(), rr
                await plc.write(cycle_request=0)
                await plc.wait_cell(lambda c: not c["done"], "done cleared")
                assert done["replayed"] is (replay or n > 0), done
                answers.append((done, rr.registers[0]))
        finally:
            plc.client.close()
        db = Path((await service.store.info()).path)
    return answers, db


def _key_request(db: Path, req_id: int) -> dict[str, Any]:
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as conn:
        row = conn.execute("SELECT request_json FROM idempotency_keys WHERE scope = 'plc' AND key = ?",
                           (str(req_id),)).fetchone()
    return json.loads(row[0])


async def _replay_after(tmp_path: Path, edit: Callable[[dict[str, Any], dict[str, Any]], Recipes]) -> None:
    side, door = _sim_recipes()
    [(first, raw1)], db = await _plc_cycle(tmp_path, [side, door], 5001, replay=False)
    assert first["ok"] and raw1 == 2 and first["result_part_id"] == 77, (first, raw1)
    # the integrator edits the recipes, the service restarts on the same workdir; the PLC repeats its request as it
    # was, then with recipe_id 1 (door-window's id after the swap): the stored result stands, flagged as not matching
    [(again, raw2), (other, raw3)], _ = await _plc_cycle(tmp_path, edit(side, door), 5001, replay=True,
                                                         recipe_ids=(2, 1))
    assert raw2 == 2 and again["result_recipe_id"] == 2, (raw2, again)
    assert not again["request_mismatch"] and again["result_part_id"] == 77 and again["ok"], again
    assert again["dx_mm"] == first["dx_mm"]  # the stored result, not a new cycle
    assert raw3 == 2 and other["request_mismatch"] and other["dx_mm"] == first["dx_mm"], (raw3, other)
    assert _key_request(db, 5001)["plc_recipe_id"] == 2  # kept with the cycle's request
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as conn:
        assert conn.execute("SELECT COUNT(*), MIN(recipe) FROM cycles").fetchone() == (1, "door-window")


async def test_a_replay_after_the_recipe_ids_were_swapped_answers_the_id_the_plc_sent(tmp_path: Path) -> None:
    await _replay_after(tmp_path, lambda side, door: [{**side, "id": 2}, {**door, "id": 1}])


async def test_a_replay_after_the_recipe_was_renamed_answers_the_id_the_plc_sent(tmp_path: Path) -> None:
    await _replay_after(tmp_path, lambda side, door: [side, {**door, "name": "door-glass"}])


async def test_a_record_from_before_the_id_was_kept_answers_its_recipe_names_id(tmp_path: Path) -> None:
    """The key as older versions stored it (no plc_recipe_id): the recipe name's id in today's configuration."""
    side, door = _sim_recipes()
    [(first, _)], db = await _plc_cycle(tmp_path, [side, door], 5002, replay=False)
    old = {k: v for k, v in _key_request(db, 5002).items() if k != "plc_recipe_id"}
    assert old == {"recipe": "door-window", "part_id": "77", "car_id": None}
    with sqlite3.connect(db) as conn:
        conn.execute("UPDATE idempotency_keys SET request_json = ? WHERE scope = 'plc' AND key = '5002'",
                     (json.dumps(old, sort_keys=True, separators=(",", ":")),))
    [(again, raw2)], _ = await _plc_cycle(tmp_path, [side, door], 5002, replay=True)
    assert raw2 == 2 and not again["request_mismatch"] and again["dx_mm"] == first["dx_mm"], (raw2, again)


async def test_a_rest_started_cycle_keeps_its_key_as_before(tmp_path: Path) -> None:
    """REST keys hold no PLC recipe_id: the request is stored (and hashed) as before, so an older key still matches."""
    side, door = _sim_recipes()
    async with running_service(tmp_path, _config([side, door])) as service, api_client(service) as client:
        await to_execute(client)
        r = await client.post("/cycle?wait=true&timeout_s=90", json={"recipe": "door-window", "part_id": "P-1"},
                              headers={**AUTH, "Idempotency-Key": "rest-1"})
        assert r.status_code == 200 and r.json()["state"] == "done", r.text
        db = Path((await service.store.info()).path)
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as conn:
        stored, digest = conn.execute("SELECT request_json, request_hash FROM idempotency_keys WHERE scope = 'rest' "
                                      "AND key = 'rest-1'").fetchone()
    assert json.loads(stored) == {"recipe": "door-window", "part_id": "P-1", "car_id": None}
    assert digest == hashlib.sha256(stored.encode()).hexdigest()
