"""Whether a folder the service needs (the store's, the OPC UA certificates') could be made, without making it."""

from __future__ import annotations

import os
from pathlib import Path


def folder_problem(folder: Path) -> str | None:
    """Why ``folder`` could not be created (``mkdir -p``) by this process now, without creating it; None if it could."""
    for p in (folder, *folder.parents):
        if not p.exists():
            continue
        if not p.is_dir():
            return f"{p} is a file, not a folder"
        if p != folder and not os.access(p, os.W_OK | os.X_OK):
            return f"no right to create a folder in {p}"
        return None
    return None
