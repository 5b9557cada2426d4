"""A recipe: a workpiece type the cell installs, with the settings of its own window.

A recipe names its PLC number and may replace, for its cycles only, the settings that belong to
the window rather than to the cell: the opening's geometry and nominal place, the laser's reading
layout, the inspection, the motion, the vision settings, and (simulated cell) the glass on the
gripper. What it leaves out is the cell's. Cameras, hand-eye and laser mountings stay per cell;
each recipe is taught on its own (``cellctl teach --recipe NAME``).

The sections a recipe may carry and where each lands in the configuration are listed once, in
:data:`RECIPE_SECTIONS`.
"""

from __future__ import annotations

from typing import Any

from pydantic import Field

from cellctl.config.types import StrictModel

# A recipe's section -> the configuration table it replaces fields of, for that recipe's cycles.
RECIPE_SECTIONS: dict[str, tuple[str, ...]] = {
    "opening": ("layout", "opening"),
    "align": ("process", "align"),
    "inspect": ("process", "inspect"),
    "motion": ("process", "motion"),
    "vision": ("vision",),
    "sim_glass": ("sim", "glass"),
}


class Recipe(StrictModel):
    """A workpiece type: its PLC number, the name records and the API use, and its own settings.

    Each section (see :data:`RECIPE_SECTIONS`) holds fields of its table, checked as that table's;
    e.g. ``[process.recipes.opening]`` with ``width_mm = 1200.0``.
    """

    id: int = Field(ge=1, le=65535)
    name: str = Field(min_length=1, max_length=64, pattern=r"^[a-z0-9][a-z0-9_.-]*$")
    description: str = ""
    opening: dict[str, Any] = {}
    align: dict[str, Any] = {}
    inspect: dict[str, Any] = {}
    motion: dict[str, Any] = {}
    vision: dict[str, Any] = {}
    sim_glass: dict[str, Any] = {}

    def overrides(self) -> dict[str, dict[str, Any]]:
        """The sections this recipe sets (empty ones left out)."""
        return {name: getattr(self, name) for name in RECIPE_SECTIONS if getattr(self, name)}

    def bare(self) -> dict[str, Any]:
        """Its number, name and description only (how a recipe's view lists every recipe)."""
        return {"id": self.id, "name": self.name, "description": self.description}


def merge_into(data: dict[str, Any], path: tuple[str, ...], fields: dict[str, Any]) -> None:
    """Set ``fields`` into the table at ``path`` of ``data`` (nested tables merged, the rest replaced)."""
    node = data
    for part in path:
        child = node.get(part)
        node[part] = child = dict(child) if isinstance(child, dict) else {}
        node = child
    _deep_merge(node, fields)


def _deep_merge(into: dict[str, Any], fields: dict[str, Any]) -> None:
    for key, value in fields.items():
        if isinstance(value, dict) and isinstance(into.get(key), dict):
            into[key] = dict(into[key])
            _deep_merge(into[key], value)
        else:
            into[key] = value
