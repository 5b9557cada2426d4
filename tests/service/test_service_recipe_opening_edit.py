"""A recipe's opening edited under the same name (the door window 100 mm wider, its glass made to match) leaves the
teaching taught for the old size: its install pose holds the old glass. The cycle is refused up front, naming the
field and the command that teaches it again; taught again for the new size it installs right; the other recipe's
teaching, recorded before teachings recorded the opening's size, is still used.

Each teaching records its settings as a teaching job does (``taught_shot`` of the recipe's view); installs are
scored against the twin's truth (``true_error``), read through httpx.
"""

from __future__ import annotations

import asyncio
import copy
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

from service_test_support import api_client, running_service, to_execute
from test_service_recipe_config_changes import commit, post, recipes_config, sim_recipes, within

from cellctl.calibration.calibration_set import CalibrationStore
from cellctl.calibration.taught_shot import taught_shot
from cellctl.config import CellConfig

CELL_PARTS = ("camera", "hand_eye", "laser")


def wider(door: dict[str, Any], by_mm: float = 100.0) -> dict[str, Any]:
    """The door window ``by_mm`` wider (T stays at its upper-right corner) and its glass made to match, gripped at its centre."""
    d = copy.deepcopy(door)
    d["opening"]["width_mm"] += by_mm
    d["sim_glass"]["width_mm"] += by_mm
    d["sim_glass"]["corner_in_flange_mm"][0] += by_mm / 2
    return d


async def truth(workdir: Path, config: CellConfig, recipe: str) -> Any:
    """The twin's truth of ``recipe``'s calibration in the cell ``config`` describes (the oracle's)."""
    async with running_service(workdir, config) as service:
        return await asyncio.to_thread(service.orchestrator.calibration.cycle_calibration, recipe)


async def test_a_wider_opening_under_the_same_name_is_refused_until_taught_again(tmp_path: Path) -> None:
    side, door = sim_recipes()
    before, after = recipes_config(None, [side, door]), recipes_config(None, [side, wider(door)])
    cals = {r: await truth(tmp_path / "oracle", before, r) for r in ("side-window", "door-window")}
    store = CalibrationStore(tmp_path / "calibration")
    when = datetime.now(timezone.utc) - timedelta(hours=1)
    # the side window's teaching recorded before teachings recorded the opening's size (an older set): still used
    older = {k: v for k, v in taught_shot(before.for_recipe("side-window")).items() if k not in ("width_mm", "height_mm")}
    commit(store, cals["side-window"], "side-window", CELL_PARTS + ("teaching", "pixel_map"), None, shot=older, when=when)
    commit(store, cals["door-window"], "door-window", ("teaching", "pixel_map"), "door-window",
           shot=taught_shot(before.for_recipe("door-window")), when=when)  # fmt: skip
    async with running_service(tmp_path / "cell", recipes_config(store.root, [side, door])) as service, api_client(service) as client:
        await to_execute(client)
        rec = (await post(client, "door-window", "door-1200")).json()
        assert rec["state"] == "done" and within(rec), (rec.get("error"), rec.get("true_error"))  # taught for this size
    async with running_service(tmp_path / "cell", recipes_config(store.root, [side, wider(door)])) as service, api_client(service) as client:
        await to_execute(client)
        status = (await client.get("/status")).json()["calibration"]["recipes"]
        assert status["side-window"]["ready"], status["side-window"]
        (problem,) = status["door-window"]["problems"]
        assert not status["door-window"]["ready"]
        assert "the opening's width_mm ([layout.opening], or recipe door-window's [process.recipes.opening]) was 1200 mm, now 1300" in problem
        assert "`cellctl teach --recipe door-window`" in problem, problem
        r = await post(client, "door-window", "door-1300")
        assert r.status_code == 409, (r.status_code, r.json().get("true_error"))
        assert "width_mm" in r.json()["detail"] and "`cellctl teach --recipe door-window`" in r.json()["detail"]
        assert [c["part_id"] for c in (await client.get("/cycles")).json()] == ["door-1200"]  # nothing installed
        rec = (await post(client, "side-window", "side-1")).json()  # the other recipe runs on
        assert rec["state"] == "done" and within(rec), (rec.get("error"), rec.get("true_error"))
        # taught again for the wider opening (the twin's truth of it, as the new teaching records it): it installs right
        wide = await truth(tmp_path / "oracle-wide", after, "door-window")
        commit(store, wide, "door-window", ("teaching", "pixel_map"), "door-window",
               shot=taught_shot(after.for_recipe("door-window")))  # fmt: skip
        assert (await client.get("/status")).json()["calibration"]["recipes"]["door-window"]["ready"]
        rec = (await post(client, "door-window", "door-1300-taught")).json()
        assert rec["state"] == "done" and within(rec), (rec.get("error"), rec.get("true_error"))
