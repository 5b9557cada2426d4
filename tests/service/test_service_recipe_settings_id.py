"""The records name which definition of a recipe installed a part: its settings id changes with an edit under the
same name, and only with one that changes what its cycles do or how the part is judged.

Scored on the part documents as the MES reads them (``GET /parts``), across restarts of the service on one store with
the configuration edited in between.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
from service_test_support import AUTH, api_client, running_service, sim_config, to_execute

pytestmark = pytest.mark.timeout(240)

ID = re.compile(r"^settings-[0-9a-f]{12}$")


async def _install(workdir: Path, recipe: str, key: str, **sections: dict[str, Any]) -> dict[str, Any]:
    """One cycle of ``recipe`` on a service started on ``workdir`` with config/sim.toml edited by ``sections``."""
    async with running_service(workdir, sim_config(plc={"enabled": False}, **sections)) as service, api_client(service) as client:
        await to_execute(client)
        r = await client.post("/cycle?wait=true&timeout_s=120", json={"recipe": recipe, "part_id": key},
                              headers={**AUTH, "Idempotency-Key": key})  # fmt: skip
        assert r.status_code in (200, 201), r.text
        page = (await client.get("/parts", params={"part_id": key})).json()
        (doc,) = page["installs"]
        assert doc["state"] == "done", doc["reason"]
        return dict(doc)


async def test_the_settings_id_follows_the_recipes_definition(tmp_path: Path) -> None:
    first = await _install(tmp_path, "side-window", "G-1")
    again = await _install(tmp_path, "side-window", "G-2", **{"alarms.watchdog": {"period_s": 1.5}})  # not a recipe's setting
    door = await _install(tmp_path, "door-window", "G-3")
    judged = await _install(tmp_path, "side-window", "G-4", **{"process.tolerance": {"position_mm": 0.45}})
    moved = await _install(tmp_path, "side-window", "G-5", **{"process.motion": {"fine_speed_mm_s": 40.0}})
    ids = [d["recipe_settings"] for d in (first, again, door, judged, moved)]
    assert all(ID.match(i) for i in ids), ids
    assert ids[0] == ids[1]  # the same definition, another watchdog period
    assert len({ids[0], ids[2], ids[3], ids[4]}) == 4, ids  # another recipe; its tolerance edited; its motion edited
    assert first["recipe"] == judged["recipe"] == moved["recipe"] == "side-window"
