"""The service audits a calibration set version it adopts but did not write itself.

:class:`CalibrationSetSource` (the cell's calibration) over a store folder, with a real store's audit log attached: a
version another process wrote (the offline CLI: another ``CalibrationStore`` object), the pointer moved back by hand and a
set file edited in place each give one ``calibration.version_changed`` entry (actor ``system``, source ``calibration``)
with the versions before and after and the writer the set file names; a version the service's own store object
committed (a job's) gives none. Peer: ``sqlite3`` on audit_log.
"""

from __future__ import annotations

import asyncio
import json
import shutil
import sqlite3
from pathlib import Path
from typing import Any

from calib_test_support import config, store_with_camera

from cellctl.calibration.calibration_set import CalibrationStore
from cellctl.calibration.set_parts import WrittenBy
from cellctl.calibration.source import CalibrationSetSource
from cellctl.store import AsyncCellStore


def _adoptions(db: Path) -> list[tuple[str, str, dict[str, Any]]]:
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as conn:
        rows = conn.execute("SELECT actor, source, action, params_json FROM audit_log ORDER BY seq").fetchall()
    return [(a, s, json.loads(p)) for a, s, act, p in rows if act == "calibration.version_changed"]


async def _until(db: Path, n: int) -> list[tuple[str, str, dict[str, Any]]]:
    for _ in range(200):
        rows = _adoptions(db)
        if len(rows) >= n:
            return rows
        await asyncio.sleep(0.02)
    return _adoptions(db)


def test_versions_the_service_did_not_write_are_audited_when_adopted(tmp_path: Path) -> None:
    root = Path(shutil.copytree(store_with_camera().root, tmp_path / "calibration"))
    asyncio.run(_adoptions_audited(root, tmp_path / "cellctl.db"))


async def _adoptions_audited(root: Path, db: Path) -> None:
    ours = CalibrationStore(root)  # the service's object: its jobs commit through it
    source = CalibrationSetSource(ours, config())
    store = await AsyncCellStore.open(db)
    try:
        source.attach_audit(store)
        camera = ours.current().part("camera")  # type: ignore[union-attr]
        assert source.summary()["version"] == 1 and _adoptions(db) == []
        # Another process (the offline CLI) stores version 2.
        who = WrittenBy(actor="alice", source="cli:offline", host="bench-pc", dataset="/data/ds", dataset_manifest_sha256="a" * 64)
        CalibrationStore(root).commit("camera", camera, note="camera: computed offline", written_by=who)
        assert source.summary()["version"] == 2
        ((actor, src, params),) = await _until(db, 1)
        assert (actor, src) == ("system", "calibration")
        assert params["version_before"] == 1 and params["version_after"] == 2 and params["written"] == "external"
        assert params["written_by"] == who.model_dump() and params["note"] == "camera: computed offline"
        # A job of the service stores version 3 (no entry: the job's own are job.start and its record); then the pointer
        # is moved back to version 2 by hand.
        ours.commit("camera", camera, note="camera: job 7")
        assert source.summary()["version"] == 3
        (root / "current").write_text("set-000002.json\n")
        assert source.summary()["version"] == 2
        rows = await _until(db, 2)
        assert [(p["version_before"], p["version_after"]) for _, _, p in rows] == [(1, 2), (3, 2)]
        # Version 2's file edited in place.
        doc = json.loads((root / "set-000002.json").read_text())
        doc["note"] = "edited"
        (root / "set-000002.json").write_text(json.dumps(doc))
        assert source.summary()["version"] == 2
        rows = await _until(db, 3)
        assert len(rows) == 3 and rows[2][2]["changed_in_place"] is True and rows[2][2]["note"] == "edited", rows
        assert rows[2][2]["version_before"] == rows[2][2]["version_after"] == 2
    finally:
        await store.close()
