"""The board jobs (camera, hand-eye, verify) and the laser calibration plan beside [layout.opening], the first
recipe's opening, so their car-body prompt names that recipe and the simulated operator brings its car body, whatever
body the last cycle left in the cell. After a door-window cycle (its 1200 x 900 mm body standing) they used to be
refused with board_not_found: the operator stuck the board beside the door window's opening. OpenCV's
findChessboardCorners, an independent detector, must find the board in every saved view; and a board_not_found
refusal asks whether that recipe's car body stands in the cell.
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import cv2
import httpx
import pytest
from service_test_support import AUTH, api_client, job_ended, running_service, sim_config

from cellctl.commissioning.prompts import Prompt, PromptKind
from cellctl.sim.operator import SimulatedOperator

pytestmark = pytest.mark.timeout(600)

FIRST, DOOR = "side-window", "door-window"  # config/sim.toml's recipes: the first one's opening is [layout.opening]
CELL = {"calibration": {"source": "set", "auto_calibrate_in_sim": False}, "plc": {"enabled": False},
        "devices": {"laser": {"kind": "sim"}, "robot": {"kind": "sim"}},
        "calibration.procedure.verify": {"laser_stands": 4}}  # fmt: skip


async def _job(client: httpx.AsyncClient, procedure: str, **options: Any) -> dict[str, Any]:
    r = await client.post("/jobs", json={"procedure": procedure, "options": options}, headers=AUTH)
    assert r.status_code == 201, r.text
    return await job_ended(client, r.json()["id"])


async def _command(client: httpx.AsyncClient, name: str) -> str:
    assert (await client.post(f"/commands/{name}", headers=AUTH)).status_code == 200
    for _ in range(500):
        state = (await client.get("/status")).json()["state"]
        if not state.endswith("ING"):
            return str(state)
        await asyncio.sleep(0.01)
    raise AssertionError("the cell stayed in an acting state")


async def _door_window_cycle(client: httpx.AsyncClient) -> None:
    """Teach the door window, install one door-window glass, and stop: its car body stays in the cell."""
    for procedure in ("teaching", "pixel_map"):
        assert (await _job(client, procedure, recipe=DOOR))["state"] == "done"
    assert await _command(client, "reset") == "IDLE" and await _command(client, "start") == "EXECUTE"
    r = await client.post("/cycle?wait=true&timeout_s=120", json={"recipe": DOOR, "part_id": "door-1"},
                          headers={**AUTH, "Idempotency-Key": "door-1"})  # fmt: skip
    assert r.status_code == 200, r.text
    cycle = (await client.get(f"/cycles/{r.json()['id']}")).json()
    assert cycle["state"] == "done" and cycle["recipe"] == DOOR, cycle
    assert await _command(client, "stop") == "STOPPED"


def _opencv_finds_the_board(dataset: str, inner_corners: tuple[int, int]) -> list[bool]:
    images = sorted(Path(dataset).rglob("*view_*.png"))
    assert images, f"no view images in {dataset}"
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH + cv2.CALIB_CB_NORMALIZE_IMAGE
    return [bool(cv2.findChessboardCorners(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE), inner_corners, flags=flags)[0])
            for p in images]  # fmt: skip


async def test_board_jobs_after_a_door_window_cycle_find_the_board_beside_the_first_recipes_opening(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    config = sim_config(**CELL)
    assert config.default_recipe == FIRST and config.for_recipe(FIRST).layout.opening == config.layout.opening
    board = tuple(config.calibration.procedure.camera.board.inner_corners)
    async with running_service(tmp_path, config) as service, api_client(service) as client:
        prompts: list[Prompt] = []
        service.jobs.desk.watch(prompts.append)
        assert await _command(client, "clear") == "STOPPED"
        for procedure in ("camera", "hand_eye", "laser"):
            assert (await _job(client, procedure))["state"] == "done"
        await _door_window_cycle(client)
        twin = service.extras["twin"].cell
        assert twin.world_config.width_mm == 1200.0  # the door window's car body stands in the cell
        prompts.clear()
        done = {p: await _job(client, p) for p in ("camera", "hand_eye", "laser", "verify")}
        assert all(job["state"] == "done" for job in done.values()), {p: j["error"] for p, j in done.items()}
        assert done["verify"]["result"]["quality"]["passed"], done["verify"]["result"]["quality"]
        for procedure in ("camera", "hand_eye", "verify"):
            found = _opencv_finds_the_board(done[procedure]["dataset"], board)  # type: ignore[arg-type]
            assert all(found), (procedure, found)
        # Each job asked for the first recipe's car body by name, and the board beside its opening.
        bodies = [p for p in prompts if p.kind is PromptKind.CAR_BODY]
        assert len(bodies) == 4 and all(p.details["recipe"] == FIRST and f"Recipe {FIRST} (2000 x 1500 mm" in p.text
                                        for p in bodies), [p.text for p in bodies]  # fmt: skip
        boards = [p for p in prompts if p.kind is PromptKind.PLACE_BOARD]
        assert len(boards) == 3 and all(f"upper-right corner of recipe {FIRST}'s 2000 x 1500 mm opening" in p.text
                                        for p in boards), [p.text for p in boards]  # fmt: skip
        assert twin.world_config.width_mm == 2000.0

        # An engineer who leaves the door window's car body in the cell: the refusal asks for the first recipe's.
        act = SimulatedOperator.act

        def wrong_body(op: SimulatedOperator, prompt: Prompt) -> Any:
            if prompt.kind is PromptKind.CAR_BODY:
                prompt = Prompt(prompt.id, prompt.job_id, prompt.kind, prompt.text, prompt.details | {"recipe": DOOR})
            return act(op, prompt)

        monkeypatch.setattr(SimulatedOperator, "act", wrong_body)
        hint = (f"is the car body of recipe {FIRST} standing in the cell? The board goes beside recipe {FIRST}'s "
                "2000 x 1500 mm opening")
        for procedure in ("camera", "verify"):
            job = await _job(client, procedure)
            assert job["state"] == "refused" and "board_not_found" in job["error"] and hint in job["error"], job["error"]
