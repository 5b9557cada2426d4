"""Whether a folder the service needs (the store's, the OPC UA certificates', the calibration store's) could be
made, without making it."""

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


def calibration_folder_problem(directory: str | Path, workdir: Path) -> str | None:
    """Why the calibration store's folder (``calibration.directory``, a relative one taken from ``workdir`` as
    ``serve --workdir`` takes it) could not be made, or, where it exists, not read and written; None if it can."""
    folder = Path(directory) if Path(directory).is_absolute() else workdir.resolve() / directory
    fix = ("set calibration.directory to a folder the service can write (e.g. \"var/calibration\" under --workdir, "
           "or /var/lib/cellctl/calibration)")
    if folder.is_dir():
        # The sets are read at start and written by every calibration: a folder that exists must allow both.
        if not os.access(folder, os.R_OK | os.W_OK | os.X_OK):
            return (f"calibration.directory {folder}: the service's user may not read and write in it; give it "
                    f"the right to, or {fix}")
        return None
    if (why := folder_problem(folder)) is None:
        return None
    return f"calibration.directory {folder}: the folder cannot be created ({why}); {fix}"
