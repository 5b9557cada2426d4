"""Each recipe's readiness over REST, and a cycle of a recipe whose own parts are not ready refused at the request.

The engineer recalibrates the laser and re-teaches the first recipe only (the README's steps without --recipe): the
door window's teaching was computed with a laser the set no longer holds. ``GET /status`` and ``GET /calibration``
say so per recipe with the command that mends it, and a door-window cycle is refused up front over REST (409), the
PLC (908) and OPC UA (BadInvalidState), nothing run, no alarm, no Hold, while the side window keeps producing. A
problem of the cell's own parts (an expired camera) keeps its path: the cycle is taken and fails with 1305.

The set holds the twin's truth for both recipes (installs are scored against the twin's truth); the part ids are
read from the store's files with json, the answers through httpx, pymodbus and asyncua.
"""

from __future__ import annotations

import asyncio
import json
import tomllib
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import httpx
import pytest
from asyncua import ua
from opcua_test_support import PASSWORD, call, ns_of, opcua_client
from plc_test_support import PlcClient
from pymodbus.client import AsyncModbusTcpClient
from service_test_support import AUTH, ROOT, alarms_listed, api_client, running_service, to_execute, truth_values

from cellctl.calibration.calibration_set import DEPENDS_ON, CalibrationStore, make_part
from cellctl.config import CellConfig, parse_config

pytestmark = pytest.mark.timeout(300)

CELL_PARTS = ("camera", "hand_eye", "laser")
OWN_PARTS = ("teaching", "pixel_map")
_TRUTH: dict[str, Any] = {}


def cell_config(cal_dir: Path | None, *, opcua: bool = False) -> CellConfig:
    """config/sim.toml (seed 3, PLC on port 0): the oracle's calibration, or the set at ``cal_dir``; OPC UA if asked."""
    data = tomllib.loads((ROOT / "config" / "sim.toml").read_text())
    data["calibration"] |= {"source": "oracle"} if cal_dir is None else {
        "source": "set", "directory": str(cal_dir), "auto_calibrate_in_sim": False}  # fmt: skip
    data["opcua"] |= {"enabled": opcua, "port": 0, "security_policies": ["Basic256Sha256_SignAndEncrypt"],
                      "allow_anonymous": False, "users": [{"name": "operator", "password": PASSWORD}]}  # fmt: skip
    data["plc"] |= {"port": 0, "scan_period_s": 0.005}
    data["api"]["port"] = 0
    data["sim"]["seed"] = 3
    return parse_config(data, "sim.toml (test)")


async def truth(workdir: Path) -> dict[str, Any]:
    """The twin's truth as the oracle teaches it, for each recipe (computed once per test process)."""
    if not _TRUTH:
        async with running_service(workdir, cell_config(None)) as service:
            calib = service.orchestrator.calibration
            _TRUTH.update({r: await asyncio.to_thread(calib.cycle_calibration, r) for r in ("side-window", "door-window")})
    return _TRUTH


def commit(store: CalibrationStore, cal: Any, recipe: str, names: tuple[str, ...], slot: str | None, when: datetime,
           valid_days: float = 90.0) -> None:
    """Commit the twin's truth of ``recipe``'s parts ``names`` at ``slot`` (None: the first recipe's place), as
    calibrated at ``when``, each computed with the parts the set holds then."""
    values, m = truth_values(cal, recipe), cal.nine_point
    for name in names:
        cur = store.current()
        inputs = {dep: cur.part(dep, slot).id for dep in DEPENDS_ON[name]} if cur else {}  # type: ignore[union-attr]
        q = {"map_residuals_mm": m.residuals_mm.tolist(), "map_rms_mm": m.rms_mm, "map_max_mm": m.max_mm} if name == "pixel_map" else None
        store.commit(name, make_part(name, values=values[name], method="twin truth", when=when, valid_days=valid_days,
                                     inputs=inputs, quality=q), now=when, recipe=slot)  # fmt: skip


def set_file(root: Path) -> dict[str, Any]:
    """The set in use, as json reads it from the store's files."""
    return json.loads((root / (root / "current").read_text().strip()).read_text())  # type: ignore[no-any-return]


async def post(client: httpx.AsyncClient, recipe: str, key: str) -> httpx.Response:
    return await client.post("/cycle?wait=true&timeout_s=90", json={"recipe": recipe, "part_id": key},
                             headers={**AUTH, "Idempotency-Key": key})  # fmt: skip


def recipe_ids() -> dict[str, int]:
    return {r["name"]: r["id"] for r in tomllib.loads((ROOT / "config" / "sim.toml").read_text())["process"]["recipes"]}


async def laser_redone_first_retaught(tmp_path: Path) -> tuple[CalibrationStore, str]:
    """Both recipes taught an hour ago; then the laser calibrated again and only the first recipe taught again.
    Returns the store and the door window's problem line, checked against the ids in the set's file."""
    cals = await truth(tmp_path / "oracle")
    store = CalibrationStore(tmp_path / "calibration")
    now = datetime.now(timezone.utc)
    commit(store, cals["side-window"], "side-window", CELL_PARTS + OWN_PARTS, None, now - timedelta(hours=1))
    commit(store, cals["door-window"], "door-window", OWN_PARTS, "door-window", now - timedelta(minutes=50))
    commit(store, cals["side-window"], "side-window", ("laser",), None, now - timedelta(minutes=30))  # `cellctl calibrate laser`
    commit(store, cals["side-window"], "side-window", OWN_PARTS, None, now - timedelta(minutes=20))  # teach, nine-point
    doc = set_file(store.root)
    laser_now, door_used = doc["parts"]["laser"]["id"], doc["recipes"]["door-window"]["teaching"]["inputs"]["laser"]
    assert laser_now != door_used and doc["parts"]["teaching"]["inputs"]["laser"] == laser_now
    return store, (f"teaching of recipe door-window: computed with laser {door_used}, but the set now holds laser "
                   f"{laser_now}; run `cellctl teach --recipe door-window` again")  # fmt: skip


async def test_status_and_calibration_name_each_recipe_that_is_not_ready_with_the_command(tmp_path: Path) -> None:
    store, door_line = await laser_redone_first_retaught(tmp_path)
    async with running_service(tmp_path / "cell", cell_config(store.root)) as service, api_client(service) as client:
        cal = (await client.get("/status")).json()["calibration"]
        assert cal["problems"] == []  # the first recipe and the cell's parts: ready, as before
        assert cal["recipes"] == {"side-window": {"ready": True, "problems": []},
                                  "door-window": {"ready": False, "problems": [door_line]}}  # fmt: skip
        view = (await client.get("/calibration")).json()
        assert view["problems"] == []
        assert view["current"]["recipes"] == {"side-window": {"taught": True, "ready": True, "problems": []},
                                              "door-window": {"taught": True, "ready": False, "problems": [door_line]}}  # fmt: skip
        # taught again: ready, at the next question
        commit(store, (await truth(tmp_path))["door-window"], "door-window", OWN_PARTS, "door-window", datetime.now(timezone.utc))
        cal = (await client.get("/status")).json()["calibration"]
        assert cal["recipes"]["door-window"] == {"ready": True, "problems": []}
        doc = (await client.get("/openapi.json")).json()["components"]["schemas"]
        assert doc["CalibrationProblems"]["properties"]["recipes"]["additionalProperties"] == {"$ref": "#/components/schemas/RecipeProblems"}
        assert set(doc["RecipeProblems"]["required"]) == {"ready", "problems"}
        assert "problems" in doc["RecipeReadiness"]["required"]


async def test_a_cycle_of_a_recipe_whose_own_parts_are_stale_is_refused_up_front_everywhere(tmp_path: Path) -> None:
    store, door_line = await laser_redone_first_retaught(tmp_path)
    reason = f"recipe door-window is not ready: {door_line}"
    config = cell_config(store.root, opcua=True)
    async with running_service(tmp_path / "cell", config) as service, api_client(service) as client:
        await to_execute(client)
        r = await post(client, "door-window", "door-stale")
        assert r.status_code == 409, r.text
        assert r.json()["detail"] == reason
        plc = PlcClient(AsyncModbusTcpClient("127.0.0.1", port=service.plc_server.port, timeout=2, retries=1), config.plc.float_word_order)
        assert await plc.client.connect()
        try:
            await plc.write(recipe_id=recipe_ids()["door-window"], part_id=77, cycle_req_id=4343, cycle_request=1)
            done = await plc.wait_cell(lambda c: c["done"] and c["cycle_ack_id"] == 4343, "the refusal", 20.0)
            assert not done["ok"] and done["error_code"] == 908, done  # docs/plc_register_map.md: recipe not taught/ready
            await plc.write(cycle_request=0)
        finally:
            plc.client.close()
        async with opcua_client(service, tmp_path) as ua_client:
            ns = await ns_of(ua_client)
            with pytest.raises(ua.uaerrors.BadInvalidState):
                await call(ua_client, ns, "Cycle.StartCycle", "door-window", "P-9", "", "req-door")
            refusal = await ua_client.get_node(ua.NodeId("cell-1.Cycle.LastRefusal", ns)).read_value()
            assert reason in refusal, refusal
        assert (await client.get("/cycles")).json() == []  # nothing ran
        assert (await client.get("/status")).json()["state"] == "EXECUTE"
        assert await alarms_listed(client) == []  # no alarm, no Hold
        side = await post(client, "side-window", "side-1")  # the other recipe keeps producing
        assert side.status_code == 200 and side.json()["state"] == "done", side.text


async def test_a_problem_of_the_cells_own_parts_keeps_its_path_the_cycle_fails_with_1305(tmp_path: Path) -> None:
    cals = await truth(tmp_path / "oracle")
    store = CalibrationStore(tmp_path / "calibration")
    now = datetime.now(timezone.utc)
    commit(store, cals["side-window"], "side-window", ("camera",), None, now - timedelta(days=100))  # out of date
    commit(store, cals["side-window"], "side-window", ("hand_eye", "laser") + OWN_PARTS, None, now - timedelta(hours=1))
    commit(store, cals["door-window"], "door-window", OWN_PARTS, "door-window", now - timedelta(hours=1))
    camera = set_file(store.root)["parts"]["camera"]
    expires = datetime.fromisoformat(camera["calibrated_utc"]) + timedelta(days=camera["valid_days"])
    async with running_service(tmp_path / "cell", cell_config(store.root)) as service, api_client(service) as client:
        cal = (await client.get("/status")).json()["calibration"]
        (line,) = cal["problems"]
        assert line.startswith(f"camera: expired on {expires:%Y-%m-%d %H:%M} UTC") and "run `cellctl calibrate camera`" in line
        assert cal["recipes"] == {name: {"ready": False, "problems": [line]} for name in ("side-window", "door-window")}
        await to_execute(client)
        r = await post(client, "door-window", "door-camera-expired")
        assert r.status_code == 200 and r.json()["state"] == "failed", r.text
        assert r.json()["result"]["error_code"] == 1305 and line in r.json()["error"]
