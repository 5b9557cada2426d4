"""Each recipe's closed loop is its own by name and by the calibration parts its cycles use: listing the recipes in
another order moves no loop, and teaching one recipe again leaves the other's loop alone.

The side window's car bodies jolt +0.15 mm along x just before the release (the door window's do not); the
installs are scored against the twin's truth (``true_error``), read through httpx.
"""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from service_test_support import AUTH, api_client, running_service, to_execute
from test_service_recipe_config_changes import commit, recipes_config, sim_recipes, truth_calibrations
from test_service_inspection import JoltingRobot

from cellctl.calibration.calibration_set import CalibrationStore, make_part
from cellctl.cell.cycle_values import CellDevices

JOLT_MM = 0.15
LOOP = {"min_samples": 3, "ewma_lambda": 0.5}


class SideJolts(JoltingRobot):
    """Jolts the side window's car bodies (the twin built a 2000 mm opening) only."""

    async def set_gripper(self, hold: bool, *, timeout_s: float) -> None:
        self._dx = JOLT_MM if self._cell.world_config.width_mm == 2000.0 else 0.0
        return await super().set_gripper(hold, timeout_s=timeout_s)


def side_jolts(service: Any) -> None:
    orch = service.orchestrator
    d = orch.devices
    orch.devices = CellDevices(d.laser, d.camera, SideJolts(d.robot, orch.truth.cell, 0.0))


async def cycle(client: Any, recipe: str, key: str) -> dict[str, Any]:
    r = await client.post("/cycle?wait=true&timeout_s=90", json={"recipe": recipe, "part_id": key},
                          headers={**AUTH, "Idempotency-Key": key})  # fmt: skip
    assert r.status_code in (200, 201), r.text
    rec = r.json()
    assert rec["state"] == "done", rec.get("error")
    return rec


async def test_listing_the_door_window_first_moves_no_loop(tmp_path: Path) -> None:
    side, door = sim_recipes()
    async with running_service(tmp_path, recipes_config(None, [side, door], **LOOP)) as service, api_client(service) as client:
        side_jolts(service)
        await to_execute(client)
        side_ids = [(await cycle(client, "side-window", f"side-{k}"))["id"] for k in range(6)]
        learnt = service.orchestrator.quality.view("side-window")["offset"]["dx_mm"]
        assert learnt < -0.1  # the side window's jolt, learnt
    async with running_service(tmp_path, recipes_config(None, [door, side], **LOOP)) as service, api_client(service) as client:
        await to_execute(client)
        loops = {v["recipe"]: v for v in (await client.get("/status", headers=AUTH)).json()["spc"]["recipes"]}
        assert loops["door-window"]["samples"] == 0 and loops["side-window"]["offset"]["dx_mm"] == learnt
        rec = await cycle(client, "door-window", "door-0")
        # the door window's car body had no jolt: its install takes no offset and lands where the twin says it should
        assert rec["result"]["spc"]["applied_offset"]["dx_mm"] == 0.0
        assert abs(rec["true_error"]["dx_mm"]) < 0.1, rec["true_error"]
        door_rows = (await client.get("/spc?recipe=door-window", headers=AUTH)).json()["history"]
        assert [h["cycle_id"] for h in door_rows] == [rec["id"]]
        side_rows = (await client.get("/spc?recipe=side-window", headers=AUTH)).json()["history"]
        assert [h["cycle_id"] for h in side_rows] == side_ids and {h["recipe"] for h in side_rows} == {"side-window"}


async def test_teaching_the_door_window_again_keeps_the_side_windows_offset(tmp_path: Path) -> None:
    cals = await truth_calibrations(tmp_path / "oracle")
    store = CalibrationStore(tmp_path / "calibration")
    commit(store, cals["side-window"], "side-window", ("camera", "hand_eye", "laser", "teaching", "pixel_map"), None)
    commit(store, cals["door-window"], "door-window", ("teaching", "pixel_map"), "door-window")
    async with running_service(tmp_path / "cell", recipes_config(store.root, **LOOP)) as service, api_client(service) as client:
        side_jolts(service)
        await to_execute(client)
        for k in range(6):
            rec = await cycle(client, "side-window", f"side-{k}")
        learnt = rec["result"]["spc"]["next_offset"]["dx_mm"]
        assert learnt < -0.1
        # `cellctl teach --recipe door-window` again: a new version of the set, none of the side window's parts changed
        old = store.current().part("teaching", "door-window")  # type: ignore[union-attr]
        again = make_part("teaching", values=old.values.model_dump(), method="twin truth",  # type: ignore[union-attr]
                          when=datetime.now(timezone.utc), valid_days=90.0, inputs=dict(old.inputs))  # type: ignore[union-attr]
        store.commit("teaching", again, recipe="door-window")
        rec = await cycle(client, "side-window", "side-after")
        assert rec["result"]["spc"]["applied_offset"]["dx_mm"] == learnt  # the loop kept its offset
        assert abs(rec["true_error"]["dx_mm"]) < 0.1, rec["true_error"]  # and took the jolt out, by the twin's truth
        events = [e for h in (await client.get("/spc?recipe=side-window", headers=AUTH)).json()["history"] for e in h["events"]]
        assert "reset_calibration" not in events
