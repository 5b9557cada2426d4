"""Who wrote a version of the calibration set, and the audit-log entries that say so.

A job of the service stores a version under its job record, whose ``job.start`` audit entry names the
engineer and where from. ``cellctl calibrate ... --dataset`` and ``cellctl teach --dataset`` compute
offline, in the CLI's own process, with no token: the version they store names its writer in the set
file (``written_by``: the OS account, ``cli:offline``, the host, the dataset's folder and the SHA-256 of
its manifest, which holds each file's SHA-256), and the CLI appends ``calibration.store`` with the same
to the cell's audit log (``[store] path`` under ``--workdir``: the log the service writes). The service
appends ``calibration.version_changed`` (actor ``system``, source ``calibration``) when it adopts a
version it did not write itself (:class:`cellctl.calibration.source.CalibrationSetSource`).
"""

from __future__ import annotations

import getpass
import os
import socket
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cellctl.calibration.set_parts import WrittenBy

if TYPE_CHECKING:
    from cellctl.calibration.calibration_set import CalibrationSet
    from cellctl.calibration.compute import Outcome
    from cellctl.calibration.dataset import Dataset
    from cellctl.config.schema import CellConfig
    from cellctl.store import CellStore

OFFLINE_SOURCE = "cli:offline"
STORE_ACTION = "calibration.store"
ADOPT_ACTION = "calibration.version_changed"
ADOPT_ACTOR = "system"
ADOPT_SOURCE = "calibration"


def os_user() -> str:
    """The OS account this process runs as, by its user id (not ``$USER``, which anyone can set)."""
    try:
        import pwd
    except ImportError:  # Windows: no uid
        return getpass.getuser()
    uid = os.getuid()
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:  # a uid with no account (a container)
        return f"uid {uid}"


def offline_writer(ds: Dataset, store_root: Path | None = None) -> WrittenBy:
    """The ``written_by`` of a version computed offline from ``ds`` by this process into the store at ``store_root``
    (its dataset named as the part names it: relative to that store when it lies in it)."""
    ref = ds.ref(store_root=store_root)
    return WrittenBy(actor=os_user(), source=OFFLINE_SOURCE, host=socket.gethostname(), dataset=ref.path,
                     dataset_manifest_sha256=ref.manifest_sha256)  # fmt: skip


def audit_db_path(config: CellConfig, workdir: Path) -> Path:
    """The cell's store file: ``[store] path``, a relative one taken from ``workdir`` (as ``cellctl serve`` does)."""
    p = Path(config.store.path)
    return p if p.is_absolute() else Path(workdir) / p


def open_audit_log(config: CellConfig, workdir: Path) -> CellStore:
    """The cell's store (created if the service never ran), for appending to its audit log; raises StoreError."""
    from cellctl.store import CellStore
    from cellctl.store.connection import make_store_folder

    path = audit_db_path(config, workdir)
    make_store_folder(path)
    return CellStore.open(path, synchronous=config.store.synchronous, busy_timeout_s=config.store.busy_timeout_s)


def store_params(saved: CalibrationSet, outcome: Outcome, store_root: Path) -> dict[str, Any]:
    """The params of the ``calibration.store`` entry of ``saved``, a version the CLI wrote."""
    who = saved.written_by
    part = saved.part(outcome.part, outcome.recipe)
    return {
        "version_before": saved.parent_version, "version_after": saved.version, "store": str(store_root),
        "part": outcome.part, "recipe": outcome.recipe, "part_id": None if part is None else part.id,
        "method": outcome.method, "host": None if who is None else who.host,
        "dataset": None if who is None else who.dataset,
        "dataset_manifest_sha256": None if who is None else who.dataset_manifest_sha256,
    }  # fmt: skip


def adoption_params(
    before: int | None, after: int | None, cal: CalibrationSet | None, damage: str | None, store_root: Path
) -> dict[str, Any]:
    """The params of a ``calibration.version_changed`` entry: the versions, and who the new set file says wrote it."""
    params: dict[str, Any] = {"version_before": before, "version_after": after, "store": str(store_root), "written": "external"}
    if before == after:
        params["changed_in_place"] = True  # the service never rewrites a version: the file was edited
    if damage is not None:
        params["damaged"] = damage
    elif cal is not None:
        params["note"] = cal.note
        params["written_by"] = None if cal.written_by is None else cal.written_by.model_dump()
    return params
