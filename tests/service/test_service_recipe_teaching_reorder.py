"""Teaching one recipe leaves every other recipe's teaching and nine-point map alone, whatever the order of
[[process.recipes]]: the door window listed first (reordered, or the side window removed and added back after it)
and taught by the real jobs (`cellctl teach --recipe door-window`, then its nine-point map) takes the first's place,
where the side window's own teaching was; the side window's moves under its name, unchanged, and both recipes
install right, in this order and back in the old one.

The side window's teaching and map are the twin's truth; installs are scored against the twin's truth
(``true_error``), the set read from its JSON file, the jobs and cycles through httpx.
"""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

import httpx
from service_test_support import AUTH, _command, api_client, running_service, to_execute
from test_service_recipe_config_changes import commit, post, recipes_config, sim_recipes, truth_calibrations, within

from cellctl.calibration.calibration_set import CalibrationStore


async def job(client: httpx.AsyncClient, procedure: str, recipe: str, timeout_s: float = 300.0) -> dict[str, Any]:
    """Run a commissioning job for ``recipe`` through the service to its end."""
    r = await client.post("/jobs", json={"procedure": procedure, "options": {"recipe": recipe}}, headers=AUTH)
    assert r.status_code == 201, r.text
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout_s
    while loop.time() < end:
        rec = (await client.get(f"/jobs/{r.json()['id']}")).json()
        if rec["state"] not in ("running", "computing"):
            return rec  # type: ignore[no-any-return]
        await asyncio.sleep(0.1)
    raise AssertionError(f"the {procedure} job did not end")


def current_file(store: CalibrationStore) -> dict[str, Any]:
    """The set in use, as its JSON file holds it."""
    name = (store.root / "current").read_text().strip()
    return json.loads((store.root / name).read_text())  # type: ignore[no-any-return]


async def test_teaching_the_recipe_now_first_keeps_the_other_recipes_parts(tmp_path: Path) -> None:
    cals = await truth_calibrations(tmp_path / "oracle")
    store = CalibrationStore(tmp_path / "calibration")
    commit(store, cals["side-window"], "side-window", ("camera", "hand_eye", "laser", "teaching", "pixel_map"), None)
    commit(store, cals["door-window"], "door-window", ("teaching", "pixel_map"), "door-window")
    before = current_file(store)["parts"]
    side, door = sim_recipes()
    async with running_service(tmp_path / "cell", recipes_config(store.root, [door, side])) as service, api_client(service) as client:
        assert await _command(client, "clear") == "STOPPED"
        for procedure in ("teaching", "pixel_map"):
            rec = await job(client, procedure, "door-window")
            assert rec["state"] == "done", (procedure, rec.get("error"))
        # the side window's own teaching and map, moved under its name as they were; the door window's new ones first
        data = current_file(store)
        assert data["recipes"]["side-window"] == {"teaching": before["teaching"], "pixel_map": before["pixel_map"]}
        assert data["parts"]["teaching"]["values"]["recipe"] == "door-window"
        assert data["parts"]["pixel_map"]["inputs"]["teaching"] == data["parts"]["teaching"]["id"]
        recipes = (await client.get("/status")).json()["calibration"]["recipes"]
        assert {r: v["problems"] for r, v in recipes.items()} == {"door-window": [], "side-window": []}
        for c in ("reset", "start"):
            await _command(client, c)
        for recipe in ("side-window", "door-window"):
            r = await post(client, recipe, f"{recipe}-door-first")
            assert r.status_code == 200 and r.json()["state"] == "done" and within(r.json()), (recipe, r.text[:400])
    # back in the old order: each recipe still reads its own teaching
    async with running_service(tmp_path / "cell", recipes_config(store.root, [side, door])) as service, api_client(service) as client:
        await to_execute(client)
        for recipe in ("side-window", "door-window"):
            rec = (await post(client, recipe, f"{recipe}-side-first")).json()
            assert rec["state"] == "done" and within(rec), (recipe, rec.get("error"), rec.get("true_error"))
            used = rec["steps"][0]["figures"]["calibration"]["parts"]["teaching"]
            assert used == (before["teaching"]["id"] if recipe == "side-window" else current_file(store)["parts"]["teaching"]["id"])
