"""Which cycle images a retention pass deletes: the files on disk and the plan over them (no I/O but the scan).

Images go oldest first while they are older than the age bound or all together exceed the size
bound, never those of a queued or running cycle; a pass leaves room under the bound for the next
cycle's images (:func:`cycle_headroom`). :mod:`cellctl.service.retention` runs the passes.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import NamedTuple

from cellctl.store import KeptImage

IMAGE_PATTERN = ("cycle-", ".png")  # the recorder's file names: cycle-<id>-<name>.png
RECENT_CYCLES = 10  # the room a pass leaves: the most one of the last this many cycles wrote
ORPHAN_GRACE_S = 600.0  # a file with no reference younger than this may be one being recorded now
GB = 1024**3
MB = 1024**2


def _size(n: float) -> str:
    return f"{n / GB:g} GB" if n >= GB else f"{n / MB:g} MB"


class DiskUsage(NamedTuple):
    total: int
    used: int
    free: int


class FileInfo(NamedTuple):
    size: int
    mtime: float


class ImageFolderUnavailable(Exception):
    """The image folder is not there or cannot be read: a pass must not take that for "no files"."""


def scan_images(image_dir: Path) -> dict[str, FileInfo]:
    """The cycle image files in ``image_dir`` (name -> size and mtime). A name that is not UTF-8
    is kept as :func:`os.fsdecode` gives it (no record can name it: :func:`storable`).

    Raises:
        ImageFolderUnavailable: the folder is not there or cannot be read.
    """
    out: dict[str, FileInfo] = {}
    try:
        entries = os.scandir(image_dir)
    except FileNotFoundError as err:
        raise ImageFolderUnavailable(f"the image folder {image_dir} is not there") from err
    except OSError as err:
        raise ImageFolderUnavailable(f"the image folder {image_dir} cannot be read ({err.strerror or err})") from err
    with entries:
        for e in entries:
            if not (e.name.startswith(IMAGE_PATTERN[0]) and e.name.endswith(IMAGE_PATTERN[1])):
                continue
            try:
                st = e.stat(follow_symlinks=False)
            except FileNotFoundError:
                continue
            if e.is_file(follow_symlinks=False):
                out[e.name] = FileInfo(st.st_size, st.st_mtime)
    return out


def storable(name: str) -> bool:
    """Whether a scanned file name can be a reference in the store (a name that is not UTF-8 cannot:
    it is an unreferenced file, and must not be passed to a query)."""
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def looks_unmounted(kept: list[KeptImage], files: Mapping[str, FileInfo]) -> str | None:
    """Why the folder scanned cannot be the one the records' images are in, or None: the store keeps
    image references of finished cycles and not one of their files is there (an empty mount point,
    or one the recorder has written only new files into). Marking them all missing would be wrong."""
    finished = {k.uri for k in kept if not k.cycle_active}
    if finished and finished.isdisjoint(files):
        return f"not one of the {len(finished)} image files the finished cycles' records keep is there"
    return None


def unlink_all(image_dir: Path, names: Iterable[str]) -> int:
    """Delete the files; returns how many were there."""
    n = 0
    for name in names:
        if "/" in name or name in ("", ".", ".."):
            continue  # a reference is a plain file name in the image folder; never follow anything else
        with contextlib.suppress(FileNotFoundError):
            (image_dir / name).unlink()
            n += 1
    return n


@dataclass(frozen=True)
class ImagePlan:
    """What an image pass does: references whose file is missing, files to delete and why, what stays."""

    missing: list[str]  # kept references of finished cycles without a file
    prune: dict[str, list[str]]  # reason -> referenced files to delete (their references are marked)
    orphans: list[str]  # files no reference names, old enough to delete
    kept_bytes: int
    kept_count: int
    oldest_kept: datetime | None


def plan_images(
    kept: list[KeptImage],
    files: Mapping[str, FileInfo],
    *,
    now: datetime,
    images_days: float | None,
    max_bytes: int | None,
    orphan_grace_s: float = ORPHAN_GRACE_S,
    stated_bound: int | None = None,
) -> ImagePlan:
    """Oldest first, delete while older than ``images_days`` or the total exceeds ``max_bytes``
    (None: no such bound; both None plans nothing and only measures). ``stated_bound`` is the bound
    the reason names when ``max_bytes`` is lower to leave room for the next cycle (default ``max_bytes``).

    ``files`` are the image files on disk, ``kept`` the references not yet pruned. Files of a
    queued or running cycle, and unreferenced files younger than ``orphan_grace_s``, are never
    chosen (they still count toward the total), nor reported missing. A file no kept reference
    names is an orphan.
    """
    by_uri: dict[str, list[KeptImage]] = {}
    for k in kept:
        by_uri.setdefault(k.uri, []).append(k)
    missing = [u for u, refs in by_uri.items() if u not in files and not any(r.cycle_active for r in refs)]
    items: list[tuple[datetime, str, int, bool, bool]] = []  # (time, name, size, protected, orphan)
    for name, info in files.items():
        refs = by_uri.get(name)
        if refs:
            t = min(r.created_at for r in refs)
            protected = any(r.cycle_active for r in refs)
            items.append((t, name, info.size, protected, False))
        else:
            t = datetime.fromtimestamp(info.mtime, timezone.utc)
            protected = (now - t).total_seconds() < orphan_grace_s
            items.append((t, name, info.size, protected, True))
    items.sort()
    total = sum(i[2] for i in items)
    cutoff = datetime.min.replace(tzinfo=timezone.utc) if images_days is None else now - timedelta(days=images_days)
    bound = total if max_bytes is None else max_bytes
    prune: dict[str, list[str]] = {}
    orphans: list[str] = []
    gone: set[str] = set()
    for t, name, size, protected, orphan in items:
        if total <= bound and t >= cutoff:
            break
        if protected:
            continue
        if t < cutoff:
            reason = f"retention: older than {images_days:g} days"
        else:
            reason = f"retention: images over their bound of {_size(stated_bound or bound)}"
        (orphans if orphan else prune.setdefault(reason, [])).append(name)
        gone.add(name)
        total -= size
    left = [i for i in items if i[1] not in gone]
    return ImagePlan(
        missing=missing,
        prune=prune,
        orphans=orphans,
        kept_bytes=sum(i[2] for i in left),
        kept_count=len(left),
        oldest_kept=min((i[0] for i in left if not i[4]), default=None),
    )


def cycle_headroom(kept: list[KeptImage], files: Mapping[str, FileInfo], bound: int) -> int:
    """The room a pass leaves under the image bound: the most image bytes one of the last
    :data:`RECENT_CYCLES` cycles wrote, so the next cycle's images fit under the bound too (at most
    half the bound, so a tiny bound does not empty the folder)."""
    per_cycle: dict[int, int] = {}
    for k in kept:
        info = files.get(k.uri)
        if info is not None:
            per_cycle[k.cycle_id] = per_cycle.get(k.cycle_id, 0) + info.size
    recent = [per_cycle[c] for c in sorted(per_cycle)[-RECENT_CYCLES:]]
    return min(max(recent, default=0), bound // 2)


def largest_cycle_in_names(files: Mapping[str, FileInfo], recent: int = RECENT_CYCLES) -> int:
    """The most image bytes one of the last ``recent`` cycles has on disk, by the recorder's file
    names (``cycle-<id>-<name>.png``): the estimate between passes, without the store."""
    per_cycle: dict[int, int] = {}
    for name, info in files.items():
        head = name[len(IMAGE_PATTERN[0]) :].split("-", 1)[0]
        if head.isdigit():
            per_cycle[int(head)] = per_cycle.get(int(head), 0) + info.size
    return max((per_cycle[c] for c in sorted(per_cycle)[-recent:]), default=0)
