"""Prompts that tell the engineer where on the wall to put something say a distance and its direction, never a
negative distance: the nine-point scale board at (-50, -35) mm is "50 mm left and 35 mm up" of the corner.

The words are read back into T0 coordinates (x right, y down from the opening's upper-right corner: the frame the
prompt's details name) and must give the place the job asks for.
"""

from __future__ import annotations

import asyncio
import re
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from service_test_support import AUTH, api_client, running_service
from test_commission_jobs import _command, _config, _start, _wait_prompt

from cellctl.commissioning import procedures
from cellctl.commissioning.plans import board_place, scale_board_at

SIGN = {"right": 1.0, "left": -1.0, "down": 1.0, "up": -1.0}
WORDS = re.compile(r"(\d+(?:\.\d+)?) mm (right|left) and (\d+(?:\.\d+)?) mm (down|up) of the (?:opening's )?upper-right corner")


def _read_back(text: str) -> tuple[float, float]:
    """The T0 place a person takes from the prompt's words (mm)."""
    found = WORDS.search(text)
    assert found is not None, text
    x, dx, y, dy = found.groups()
    return SIGN[dx] * float(x), SIGN[dy] * float(y)


def _place_board_text(config: Any, place: dict[str, Any]) -> str:
    asked: dict[str, str] = {}

    async def ask(kind: Any, text: str, **_: Any) -> Any:
        asked["text"] = text
        return SimpleNamespace(value=None)

    asyncio.run(procedures.place_board(SimpleNamespace(ask=ask, config=config), place, "scale checkerboard", "side-window"))
    return asked["text"]


@pytest.mark.parametrize("at_mm", [(-50.0, -35.0), (50.0, 35.0), (-12.5, 40.0), (120.0, -7.0), (0.0, -20.0)])
def test_the_board_prompt_gives_the_place_as_distances_and_directions(at_mm: tuple[float, float]) -> None:
    config = _config()
    place = board_place(config, config.calibration.procedure.nine_point.scale_board, at_mm)
    text = _place_board_text(config, place)
    assert not re.search(r"-\d", text), text  # no negative distance
    assert place["frame"].startswith("T0 (x right, y down") and _read_back(text) == at_mm, text


def test_the_nine_point_scale_board_prompt_reads_back_to_its_place() -> None:
    config = _config(**{"calibration.procedure.nine_point": {"scale_board_on_wall_mm": [-50.0, -35.0]}})
    at = scale_board_at(config)  # where the nine-point job asks for the scale board
    text = _place_board_text(config, board_place(config, config.calibration.procedure.nine_point.scale_board, at))
    assert _read_back(text) == pytest.approx(at), text


async def test_the_laser_jobs_car_body_prompt_names_the_aim_by_direction(tmp_path: Path) -> None:
    async with running_service(tmp_path, _config(answers="none")) as service, api_client(service) as client:
        assert await _command(client, "clear") == "STOPPED"
        job = await _start(client, "laser")
        prompt = await _wait_prompt(client, job["id"], "car_body_in_place")
        assert _read_back(prompt["text"]) == pytest.approx(service.config.calibration.procedure.laser.aim_mm), prompt["text"]
        await client.post(f"/jobs/{job['id']}/cancel", headers=AUTH)
