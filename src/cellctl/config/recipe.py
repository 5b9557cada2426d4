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

from pydantic import Field, ValidationError, model_validator
from pydantic_core import InitErrorDetails, PydanticCustomError

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

    @model_validator(mode="before")
    @classmethod
    def _only_its_own_sections(cls, data: Any) -> Any:
        """Refuse a key that is not a recipe's, naming the sections a recipe may set and where the key belongs."""
        if not isinstance(data, dict):
            return data
        allowed = ", ".join(f"[process.recipes.{name}]" for name in RECIPE_SECTIONS)
        errors = []
        for key in (k for k in data if k not in cls.model_fields):
            home = cell_table_of(str(key))
            where = (f"it is the cell's, for every recipe: set it in [{home}]" if home is not None
                     else "it is no setting of a recipe: check its spelling")  # fmt: skip
            text = (f"a recipe may set only its id, name, description and the sections {allowed} (fields of the tables "
                    f"they name); {where}")
            errors.append(InitErrorDetails(type=PydanticCustomError("not_a_recipe_setting", text), loc=(key,), input=data[key]))
        if errors:  # each at its own key, as pydantic names a field
            raise ValidationError.from_exception_data(cls.__name__, errors)
        return data

    def overrides(self) -> dict[str, dict[str, Any]]:
        """The sections this recipe sets (empty ones left out)."""
        return {name: getattr(self, name) for name in RECIPE_SECTIONS if getattr(self, name)}

    def bare(self) -> dict[str, Any]:
        """Its number, name and description only (how a recipe's view lists every recipe)."""
        return {"id": self.id, "name": self.name, "description": self.description}


def cell_table_of(key: str) -> str | None:
    """The configuration table named ``key``, as TOML writes it (``tolerance`` -> ``process.tolerance``), or None."""
    from cellctl.config.schema import CellConfig  # the root imports this module

    tables: list[tuple[str, type[Any]]] = [("", CellConfig)]
    for prefix, model in tables:
        for name, field in model.model_fields.items():
            kind = field.annotation
            if isinstance(kind, type) and issubclass(kind, StrictModel):
                if name == key:
                    return prefix + name
                if not prefix:
                    tables.append((f"{name}.", kind))
    return None


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
