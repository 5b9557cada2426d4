"""A recipe's own teaching is found by its name when the list of recipes changes (the side window taken out, or
renamed), and a recipe whose teaching is another's is refused up front (409 / PLC 908, no alarm, no Hold).

A calibration set holds the twin's truth for both recipes (each teaching recording its recipe); installs are
scored against the twin's truth (``true_error``) and read through httpx and pymodbus.
"""

from __future__ import annotations

import asyncio
import tomllib
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import httpx
from plc_test_support import PlcClient
from pymodbus.client import AsyncModbusTcpClient
from service_test_support import AUTH, ROOT, _command, alarms_listed, api_client, running_service, to_execute, truth_values

from cellctl.calibration.calibration_set import DEPENDS_ON, CalibrationStore, make_part
from cellctl.config import CellConfig, parse_config
from cellctl.plc.register_map import PlcErrorCode


def recipes_config(cal_dir: Path | None, recipes: list[dict[str, Any]] | None = None, **spc: float) -> CellConfig:
    """config/sim.toml (seed 3, OPC UA off, PLC on port 0): the oracle's calibration, or the set at ``cal_dir``."""
    data = tomllib.loads((ROOT / "config" / "sim.toml").read_text())
    data["calibration"] |= {"source": "oracle"} if cal_dir is None else {
        "source": "set", "directory": str(cal_dir), "auto_calibrate_in_sim": False}  # fmt: skip
    data["opcua"]["enabled"] = False
    data["plc"] |= {"port": 0, "scan_period_s": 0.005}
    data["api"]["port"] = 0
    data["sim"]["seed"] = 3
    data["process"]["spc"] |= spc
    if recipes is not None:
        data["process"]["recipes"] = recipes
    return parse_config(data, "sim.toml (test)")


def sim_recipes() -> list[dict[str, Any]]:
    return list(tomllib.loads((ROOT / "config" / "sim.toml").read_text())["process"]["recipes"])


def commit(store: CalibrationStore, cal: Any, recipe: str, names: tuple[str, ...], slot: str | None, *,
           when: datetime | None = None, g_shift_mm: float = 0.0, shot: dict[str, Any] | None = None) -> None:
    """Commit the twin's truth of ``recipe``'s parts ``names`` at ``slot`` (None: ``parts``, the first's place);
    ``g_shift_mm`` moves the taught install pose along x (a teaching that installs that far off); the teaching records
    ``shot`` (None: what truth_values gives)."""
    values, m, now = truth_values(cal, recipe), cal.nine_point, when or datetime.now(timezone.utc)
    values["teaching"]["g_Pos_0"][0][3] += g_shift_mm
    if shot is not None:
        values["teaching"]["shot"] = shot
    for name in names:
        cur = store.current()
        inputs = {dep: cur.part(dep, slot).id for dep in DEPENDS_ON[name]} if cur else {}  # type: ignore[union-attr]
        q = {"map_residuals_mm": m.residuals_mm.tolist(), "map_rms_mm": m.rms_mm, "map_max_mm": m.max_mm} if name == "pixel_map" else None
        part = make_part(name, values=values[name], method="twin truth", when=now, valid_days=90.0, inputs=inputs, quality=q)
        store.commit(name, part, now=now, recipe=slot)


async def truth_calibrations(workdir: Path) -> dict[str, Any]:
    async with running_service(workdir, recipes_config(None)) as service:
        calib = service.orchestrator.calibration
        return {r: await asyncio.to_thread(calib.cycle_calibration, r) for r in ("side-window", "door-window")}


async def post(client: httpx.AsyncClient, recipe: str, key: str) -> httpx.Response:
    return await client.post("/cycle?wait=true&timeout_s=90", json={"recipe": recipe, "part_id": key},
                             headers={**AUTH, "Idempotency-Key": key})  # fmt: skip


def within(rec: dict[str, Any], mm: float = 0.5, deg: float = 1.0) -> bool:
    te = rec["true_error"]
    return all(abs(te[k]) < mm for k in ("dx_mm", "dy_mm", "dz_mm")) and all(abs(te[k]) < deg for k in ("drx_deg", "dry_deg", "drz_deg"))


async def test_the_door_window_left_alone_runs_on_its_own_teaching_and_a_new_one_taught_in_first_place(tmp_path: Path) -> None:
    cals = await truth_calibrations(tmp_path / "oracle")
    store = CalibrationStore(tmp_path / "calibration")
    old = datetime.now(timezone.utc) - timedelta(hours=1)
    commit(store, cals["side-window"], "side-window", ("camera", "hand_eye", "laser", "teaching", "pixel_map"), None, when=old)
    commit(store, cals["door-window"], "door-window", ("teaching", "pixel_map"), "door-window", when=old)
    side, door = sim_recipes()
    async with running_service(tmp_path / "cell", recipes_config(store.root, [door])) as service, api_client(service) as client:
        await to_execute(client)
        r = await post(client, "door-window", "door-alone")
        rec = r.json()
        assert r.status_code == 200 and rec["state"] == "done", (r.status_code, rec.get("error") or rec.get("detail"))
        assert within(rec), rec["true_error"]  # its own teaching and map, by the twin's truth
        assert rec["steps"][0]["figures"]["calibration"]["parts"]["teaching"] == store.current().part("teaching", "door-window").id  # type: ignore[union-attr]
        # an older teaching under its name (one that installs 3 mm off); then `cellctl teach` and nine-point with the
        # door window first write in the first's place: the newer teaching there is the one read
        commit(store, cals["door-window"], "door-window", ("teaching",), "door-window", when=old, g_shift_mm=3.0)
        commit(store, cals["door-window"], "door-window", ("teaching", "pixel_map"), None)
        rec = (await post(client, "door-window", "door-retaught")).json()
        assert rec["state"] == "done" and within(rec), (rec.get("error"), rec.get("true_error"))
        assert rec["steps"][0]["figures"]["calibration"]["parts"]["teaching"] == store.current().part("teaching").id  # type: ignore[union-attr]
        assert not await alarms_listed(client)


async def test_a_renamed_first_recipe_is_refused_up_front_over_rest_and_the_plc(tmp_path: Path) -> None:
    cals = await truth_calibrations(tmp_path / "oracle")
    store = CalibrationStore(tmp_path / "calibration")
    commit(store, cals["side-window"], "side-window", ("camera", "hand_eye", "laser", "teaching", "pixel_map"), None)
    commit(store, cals["door-window"], "door-window", ("teaching", "pixel_map"), "door-window")
    side, door = sim_recipes()
    config = recipes_config(store.root, [{**side, "name": "side-glass"}, door])
    async with running_service(tmp_path / "cell", config) as service, api_client(service) as client:
        await to_execute(client)
        r = await post(client, "side-glass", "renamed-1")
        assert r.status_code == 409, r.text
        assert r.json()["detail"] == "recipe side-glass is not taught: its teaching is missing; run `cellctl teach --recipe side-glass`"
        plc = PlcClient(AsyncModbusTcpClient("127.0.0.1", port=service.plc_server.port, timeout=2, retries=1), config.plc.float_word_order)
        assert await plc.client.connect()
        try:
            await plc.write(recipe_id=side["id"], part_id=77, cycle_req_id=4242, cycle_request=1)
            done = await plc.wait_cell(lambda c: c["done"] and c["cycle_ack_id"] == 4242, "the refusal", 20.0)
            assert not done["ok"] and done["error_code"] == int(PlcErrorCode.RECIPE_NOT_TAUGHT), done
            await plc.write(cycle_request=0)
        finally:
            plc.client.close()
        status = (await client.get("/status")).json()
        assert status["state"] == "EXECUTE" and not await alarms_listed(client)  # no Hold, no alarm
        assert (await client.get("/cycles")).json() == []
        # the door window's own teaching still runs it, by the twin's truth
        rec = (await post(client, "door-window", "door-1")).json()
        assert rec["state"] == "done" and within(rec), (rec.get("error"), rec.get("true_error"))


async def test_a_job_of_an_untaught_recipe_names_the_command_that_teaches_it(tmp_path: Path) -> None:
    """`cellctl calibrate nine-point --recipe door-window` before the door window is taught: the refusal names
    `cellctl teach --recipe door-window`, as the plan and a refused cycle do (it named only the missing part)."""
    cals = await truth_calibrations(tmp_path / "oracle")
    store = CalibrationStore(tmp_path / "calibration")
    commit(store, cals["side-window"], "side-window", ("camera", "hand_eye", "laser", "teaching", "pixel_map"), None)
    async with running_service(tmp_path / "cell", recipes_config(store.root)) as service, api_client(service) as client:
        assert [await _command(client, c) for c in ("clear", "reset")] == ["STOPPED", "IDLE"]  # Idle: jobs may run
        r = await client.post("/jobs", json={"procedure": "pixel_map", "options": {"recipe": "door-window"}}, headers=AUTH)
        assert r.status_code == 409, r.text
        assert r.json()["detail"] == ("pixel_map (recipe door-window) needs teaching calibrated first: "
                                      "run `cellctl teach --recipe door-window`")  # fmt: skip
        assert service.jobs.running() is None
