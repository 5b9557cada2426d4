"""A short id of the settings one recipe's cycles run with, for the records (which definition installed a part).

A recipe is named in the records by its name; an edit under the same name (its opening, spots, flush
spots, motion, vision, or the cell's tables it inherits) changes what a cycle does without changing
the name. The id digests the tables a recipe may set (:data:`~cellctl.config.recipe.RECIPE_SECTIONS`)
and the tolerance the part is judged by, as the recipe's view of the configuration holds them.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

from pydantic import BaseModel

from cellctl.config.recipe import RECIPE_SECTIONS

JUDGED_BY: tuple[tuple[str, ...], ...] = (("process", "tolerance"),)
"""Tables outside a recipe's sections that still decide its part's result."""


def recipe_settings_id(view: BaseModel) -> str:
    """``settings-`` and 12 hex digits of the SHA-256 of the recipe's settings (``view``: ``config.for_recipe(name)``)."""
    tables: dict[str, Any] = {}
    for path in (*RECIPE_SECTIONS.values(), *JUDGED_BY):
        node: Any = view
        for part in path:
            node = getattr(node, part)
        tables[".".join(path)] = node.model_dump(mode="json")
    text = json.dumps(tables, sort_keys=True, separators=(",", ":"))
    return "settings-" + hashlib.sha256(text.encode("utf-8")).hexdigest()[:12]
