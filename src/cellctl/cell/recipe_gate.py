"""Whether the calibration lets each recipe run: the per-recipe verdicts of ``/status``, and the refusal of a
cycle request whose recipe is not taught or whose own parts (teaching, nine-point map) are not ready."""

from __future__ import annotations

from collections.abc import Iterable
from datetime import datetime, timezone
from typing import Any

from cellctl.cell.sources import CalibrationSource, RecipePartsCheck


def calibration_status(calibration: CalibrationSource, recipes: Iterable[str]) -> dict[str, Any]:
    """``/status`` calibration: ``problems`` of the cell's first recipe (the cell's parts included), and for each
    of ``recipes`` whether it is ready and its own lines (the cell's parts included)."""
    now = datetime.now(timezone.utc)  # one instant for every verdict: a part expiring meanwhile cannot split them
    by_recipe = {name: calibration.problems(name, now=now) for name in recipes}
    return {
        "problems": calibration.problems(now=now),
        "recipes": {name: {"ready": not lines, "problems": lines} for name, lines in by_recipe.items()},
    }


def cycle_refusal(calibration: CalibrationSource, recipe: str) -> str | None:
    """Why a cycle of ``recipe`` is refused at the request (untaught, or its own parts not ready), with the command
    that fixes it; None when it may be queued (the cell's own parts are checked when the cycle starts, as before)."""
    why = calibration.untaught(recipe)
    if why is not None or not isinstance(calibration, RecipePartsCheck):
        return why
    lines = calibration.recipe_problems(recipe)
    return f"recipe {recipe} is not ready: " + "; ".join(lines) if lines else None
