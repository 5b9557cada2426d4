"""Calibration datasets on disk: everything a calibration was computed from, to recompute and audit it.

A dataset is a folder with ``manifest.json`` and the images as lossless PNG. The manifest holds
the kind, when and where the data came from, the robot poses as the controller reported them
(4x4, mm), the readings, and a SHA-256 of every image; reading a dataset checks them, so an
image changed after the fact is refused. The calibration set records the manifest's own SHA-256
with the part computed from it.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
import uuid
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.calibration.calibration_set import DatasetRef, _jsonable

FORMAT = "cellctl-calibration-dataset"
KINDS = ("board_views", "laser_plane", "nine_point", "teaching", "verify")


class DatasetError(ValueError):
    """A dataset folder cannot be used; the message says which file or field and why."""


@dataclass(frozen=True)
class Dataset:
    """A dataset read back: its folder and manifest; images are loaded on demand."""

    root: Path
    manifest: dict[str, Any]
    # What the job that wrote it did beside it, for the job's result (not in the manifest; e.g. the check datasets
    # pruned after a drift check, cellctl.calibration.dataset_retention). Empty when read back from disk.
    notes: dict[str, Any] = field(default_factory=dict, compare=False)

    @property
    def kind(self) -> str:
        return str(self.manifest["kind"])

    @property
    def measured_utc(self) -> datetime | None:
        """When the cell was measured: the manifest's ``written_utc`` (the end of the capture), None if unreadable."""
        try:
            t = datetime.fromisoformat(str(self.manifest["written_utc"]))
        except (KeyError, ValueError):
            return None
        return t.astimezone(timezone.utc) if t.tzinfo is not None else None

    def image(self, name: str) -> NDArray[np.uint8]:
        """An image of the dataset, checked against its recorded SHA-256."""
        files = self.manifest.get("files", {})
        if name not in files:
            raise DatasetError(f"{self.root}: the manifest lists no image {name!r}")
        path = self.root / name
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            raise DatasetError(f"{path}: image missing from the dataset") from None
        if hashlib.sha256(data).hexdigest() != files[name]:
            raise DatasetError(f"{path}: the image changed since it was recorded (SHA-256 differs); the dataset is not the original")
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        if img is None or img.ndim != 2 or img.dtype != np.uint8:
            raise DatasetError(f"{path}: not an 8-bit mono PNG")
        return img

    def ref(self, summary: dict[str, Any] | None = None, *, store_root: str | Path | None = None) -> DatasetRef:
        """The reference a calibration part keeps to this dataset; its path as :func:`stored_path` writes it."""
        digest = hashlib.sha256((self.root / "manifest.json").read_bytes()).hexdigest()
        return DatasetRef(kind=self.kind, path=stored_path(self.root, store_root), manifest_sha256=digest,
                          summary=_jsonable(summary or {}))  # fmt: skip


def stored_path(folder: str | Path, store_root: str | Path | None) -> str:
    """How a set file (or a check's manifest) names dataset ``folder``: relative to the calibration store folder
    ``store_root`` when it lies in it (``datasets/<name>``: it moves with the store), else absolute."""
    here = Path(os.path.abspath(folder))
    if store_root is not None:
        for to_path in (os.path.abspath, os.path.realpath):  # as given, then with symbolic links resolved
            try:
                return Path(to_path(folder)).relative_to(to_path(store_root)).as_posix()
            except ValueError:
                continue
    return str(here)


def dataset_folder(stored: str, store_root: str | Path | None) -> Path:
    """The folder a dataset path stored by :func:`stored_path` names now, in the store at ``store_root``.

    A relative path is taken from ``store_root``. An absolute one (written so by releases before relative paths, or a
    dataset outside the store) is used as stored where it exists, else ``<store_root>/datasets/<its name>``: the store
    was moved (a new PC, a backup restored elsewhere) and its datasets with it. The manifest SHA-256 a part records
    still tells a wrong folder. ``store_root`` None: the path as stored.
    """
    p = Path(stored)
    if store_root is None:
        return p
    if not p.is_absolute():
        return Path(store_root) / p
    if p.is_dir():
        return p
    moved = Path(store_root) / "datasets" / p.name
    return moved if moved.is_dir() else p


def pose_list(T: NDArray[np.float64]) -> list[list[float]]:
    return np.asarray(T, dtype=float).tolist()  # type: ignore[no-any-return]


def pose_array(v: Any, what: str) -> NDArray[np.float64]:
    a = np.asarray(v, dtype=float)
    if a.shape != (4, 4) or not np.all(np.isfinite(a)):
        raise DatasetError(f"{what}: expected a finite 4x4 pose, got shape {a.shape}")
    return a


def default_dataset_dir(store_root: str | Path, kind: str, when: datetime | None = None) -> Path:
    """``<store>/datasets/<kind>-<UTC time>``: where a new dataset of ``kind`` goes."""
    t = (when or datetime.now(timezone.utc)).astimezone(timezone.utc)
    return Path(store_root) / "datasets" / f"{kind}-{t:%Y%m%dT%H%M%S}Z"


def write_dataset(root: str | Path, kind: str, manifest: dict[str, Any], images: dict[str, NDArray[np.uint8]]) -> Dataset:
    """Write the images and the manifest (with their checksums) into a new folder ``root``.

    They are written into a hidden folder beside it, renamed to ``root`` once complete: a dataset folder
    is whole or absent, and of two writers to one ``root`` the second is refused (never mixed in).
    """
    if kind not in KINDS:
        raise ValueError(f"unknown dataset kind {kind!r}; the kinds are {', '.join(KINDS)}")
    folder = Path(root)
    if folder.exists() and any(folder.iterdir()):
        raise DatasetError(f"{folder}: the folder is not empty; a dataset is never written over another one")
    for name in images:
        if not name.endswith(".png") or "/" in name:
            raise ValueError(f"image names must be plain '*.png' file names, got {name!r}")
    folder.parent.mkdir(parents=True, exist_ok=True)
    work = folder.parent / f".{folder.name}.writing-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    work.mkdir()
    try:
        files = {}
        for name, img in images.items():
            ok, buf = cv2.imencode(".png", np.ascontiguousarray(img))
            if not ok:
                raise DatasetError(f"{name}: could not encode the image as PNG")
            data = buf.tobytes()
            (work / name).write_bytes(data)
            files[name] = hashlib.sha256(data).hexdigest()
        doc = {"format": FORMAT, "kind": kind, "written_utc": datetime.now(timezone.utc).isoformat(), "files": files}
        doc.update(_jsonable(manifest))
        (work / "manifest.json").write_text(json.dumps(doc, indent=1), encoding="utf-8")
        try:
            os.rename(work, folder)  # onto a missing or empty folder only
        except OSError as err:
            if err.errno not in (errno.ENOTEMPTY, errno.EEXIST):
                raise
            raise DatasetError(f"{folder}: the folder is not empty; a dataset is never written over another one") from None
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    return Dataset(folder, doc)


def read_dataset(root: str | Path, kind: str, *, allow_partial: bool = False) -> Dataset:
    """Open a dataset folder of the expected ``kind`` (its images are checked when loaded).

    A partial dataset (its job was cancelled or failed) is refused unless ``allow_partial``.
    """
    folder = Path(root)
    path = folder / "manifest.json"
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DatasetError(f"{folder}: no manifest.json; not a calibration dataset folder") from None
    except json.JSONDecodeError as err:
        raise DatasetError(f"{path}: not valid JSON ({err.msg} at line {err.lineno})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise DatasetError(f"{path}: format must be {FORMAT!r}; not a calibration dataset")
    if doc.get("kind") != kind:
        raise DatasetError(f"{path}: this is a {doc.get('kind')!r} dataset, the command needs a {kind!r} dataset")
    if not isinstance(doc.get("files"), dict):
        raise DatasetError(f"{path}: the manifest has no 'files' table")
    if doc.get("partial") and not allow_partial:
        raise DatasetError(
            f"{folder}: a partial dataset ({doc.get('ended', 'the job ended early')}); it is kept for the record, "
            "but a calibration needs a complete one: collect again"
        )
    return Dataset(folder, doc)
