"""How many drift-check datasets the calibration store keeps (``calibration.procedure.verify.keep_datasets``).

Every ``cellctl calibrate verify`` writes a ``verify-<time>`` dataset into ``<store>/datasets``
(24 board views of 2 MiB each with a 2048 x 2048 px camera, and the laser readings: about 47 MiB).
A check only reads the camera, hand-eye and laser datasets of the set in use, so after each check the oldest
``verify`` datasets beyond the newest ``keep`` are removed. Never removed: the one just written,
any dataset a version of the calibration set (the one in use or an older one) names, a folder
that is not a readable ``verify`` dataset, and anything at all while a set file cannot be read
(what it names is unknown then). Datasets of the other kinds are always kept.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from cellctl.calibration.dataset import FORMAT

log = logging.getLogger(__name__)

MB = 1024**2
CHECK_KIND = "verify"
PRUNING = ".pruning"  # a folder being removed is first renamed to ".<name>.pruning": whole or gone for a reader


@dataclass(frozen=True)
class PruneReport:
    """What a pass did: the check datasets kept and removed, and the datasets folder's size after it (MiB)."""

    keep: int  # calibration.procedure.verify.keep_datasets
    kept: int  # check datasets left in the folder
    pruned: list[str] = field(default_factory=list)  # folder names removed, oldest first
    freed_mb: float = 0.0
    folder_mb: float = 0.0  # all datasets in the folder, every kind
    held: str | None = None  # why nothing was removed, when something kept the pass from it

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def folder_bytes(folder: Path) -> int:
    """The bytes of the files under ``folder`` (0 if it is missing)."""
    total = 0
    for top, _, files in os.walk(folder):
        for f in files:
            try:
                total += os.lstat(os.path.join(top, f)).st_size
            except OSError:
                pass  # removed meanwhile
    return total


def referenced_names(store_root: Path) -> set[str]:
    """The folder names of every path any ``set-*.json`` of the store holds (a dataset is matched by its name, so a
    store moved to another folder still protects its datasets). Raises OSError / ValueError for a set file that
    cannot be read, and ValueError when the store holds no set at all."""
    files = sorted(store_root.glob("set-*.json"))
    if not files:
        raise ValueError(f"{store_root}: no calibration set file (set-*.json) to tell which datasets are in use")
    names: set[str] = set()

    def walk(v: Any) -> None:
        if isinstance(v, dict):
            for item in v.values():
                walk(item)
        elif isinstance(v, list):
            for item in v:
                walk(item)
        elif isinstance(v, str) and v:
            names.add(Path(v).name)

    for f in files:
        try:
            walk(json.loads(f.read_text(encoding="utf-8")))
        except (OSError, ValueError) as err:
            raise ValueError(f"{f} cannot be read ({err}); restore it from a backup") from None
    return names


def _is_check(folder: Path) -> bool:
    """A complete or partial ``verify`` dataset written by the cell (its manifest says so)."""
    try:
        doc = json.loads((folder / "manifest.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(doc, dict) and doc.get("format") == FORMAT and doc.get("kind") == CHECK_KIND


def _remove(folder: Path) -> int:
    """Remove a dataset folder; its size in bytes. Renamed aside first, so it is never seen half removed."""
    size = folder_bytes(folder)
    aside = folder.with_name(f".{folder.name}{PRUNING}")
    os.rename(folder, aside)
    shutil.rmtree(aside, ignore_errors=True)  # what is left of it goes at the next pass
    return size


def prune_check_datasets(store_root: str | Path, keep: int, *, just_written: str | Path) -> PruneReport:
    """Remove the oldest ``verify`` datasets of ``<store_root>/datasets`` beyond the newest ``keep`` (see the module)."""
    root = Path(store_root)
    folder = root / "datasets"
    newest = Path(just_written).name
    for left in folder.glob(f".*{PRUNING}"):  # a pass stopped mid-way: finish it
        shutil.rmtree(left, ignore_errors=True)
    names = sorted(os.listdir(folder)) if folder.is_dir() else []  # "verify-YYYYmmddTHHMMSSZ...": oldest first
    checks = [folder / n for n in names if n.startswith(f"{CHECK_KIND}-") and (folder / n).is_dir() and _is_check(folder / n)]
    try:
        in_use = referenced_names(root)
    except (OSError, ValueError) as err:
        held = f"no check dataset removed: {err}"  # what an unreadable set file names is unknown
        log.warning("calibration datasets: %s", held)
        return PruneReport(keep, len(checks), held=held, folder_mb=round(folder_bytes(folder) / MB, 3))
    # The one just written counts among the ``keep`` newest; one a set version names counts in neither.
    others = [p for p in checks if p.name != newest and p.name not in in_use]
    pruned: list[str] = []
    freed = 0
    for p in others[: max(0, len(others) - (keep - 1))]:
        try:
            freed += _remove(p)
        except OSError as err:
            log.warning("calibration datasets: %s could not be removed (%s); kept", p, err)
            continue
        pruned.append(p.name)
    report = PruneReport(keep, len(checks) - len(pruned), pruned, round(freed / MB, 3), round(folder_bytes(folder) / MB, 3))
    if pruned:
        log.info(
            "calibration datasets: removed %d drift-check dataset%s (%s; %.1f MiB), keeping the newest %d "
            "(calibration.procedure.verify.keep_datasets); %s holds %.1f MiB",
            len(pruned), "" if len(pruned) == 1 else "s", ", ".join(pruned), report.freed_mb, keep, folder, report.folder_mb,
        )  # fmt: skip
    return report
