"""The cycle's calibration from the versioned calibration set (the cell's CalibrationSource).

The set is read from its folder when it changes: every call looks at the ``current`` pointer's
and the set file's identity (inode, size, modification and change times; two ``stat`` calls) and
reads and validates the file only when one of them differs from the last read, so a new version
is picked up at the next call and /status, which asks four times a second, costs no parsing.
The set is checked for completeness, validity and age (:func:`check_ready`) and turned into what
a cycle needs. The set changes only through commissioning jobs (:mod:`cellctl.commissioning`) or
``cellctl calibrate ... --dataset``.

A damaged file (not JSON, a bad field, a pointer naming nothing) is refused once per change of
the file: one warning in the log naming the file and the field, one alarm
(:attr:`AlarmCode.CALIBRATION_INVALID`, source ``calibration``, when :meth:`attach_alarms` was
called), and from then on :meth:`problems` names the damage (so a cycle fails with that alarm's
code, 1305), :meth:`cycle_calibration` raises :class:`CalibrationRefused`, and the status,
summary and history keep answering.

A version the service did not write itself (``cellctl calibrate ... --dataset``, a pointer moved back
by hand, a file edited in place; not a damaged one, which is refused) is logged and, once
:meth:`attach_audit` was called, audited when it is adopted: ``calibration.version_changed`` (actor
``system``, source ``calibration``) with the version before and after and whom the new set file
names as its writer (``written_by``, None if no one); see :mod:`cellctl.calibration.provenance`.
A job's version is audited with the job (``job.start``).
"""

from __future__ import annotations

import asyncio
import logging
import os
import threading
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from cellctl.calibration.calibration_set import (
    PART_NAMES,
    RECIPE_PART_NAMES,
    CalibrationSet,
    CalibrationStore,
    command,
    damage_text,
    history_row,
    parts_of,
    recipe_named,
    store_root,
    taught_for,
)
from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.provenance import ADOPT_ACTION, ADOPT_ACTOR, ADOPT_SOURCE, adoption_params
from cellctl.calibration.readiness import check_ready, expires_utc
from cellctl.calibration.taught_shot import taught_profile_of
from cellctl.cell.cycle_values import CycleCalibration
from cellctl.config.schema import CellConfig
from cellctl.vision import AffineMap, CornerFeatures

if TYPE_CHECKING:
    from collections.abc import Callable, Coroutine

    from cellctl.cell.alarms import AlarmManager
    from cellctl.store import AsyncCellStore

log = logging.getLogger(__name__)

FileSig = tuple[int, int, int, int] | None  # (inode, size, mtime_ns, ctime_ns); None: no such file

def cycle_calibration_from_set(
    cal: CalibrationSet, laser_range_mm: tuple[float, float], recipe: str | None = None
) -> CycleCalibration:
    """The parts a cycle of ``recipe`` (None: the cell's first) needs, from a set that :func:`check_ready` accepts."""
    r, l = cal.laser_ray()  # noqa: E741
    pixel_map = cal.part("pixel_map", recipe)
    q = pixel_map.quality if pixel_map is not None else {}
    residuals = np.asarray(q.get("map_residuals_mm", []), dtype=float)
    nine_point = AffineMap(cal.pixel_affine(recipe), residuals, float(q.get("map_rms_mm", 0.0)), float(q.get("map_max_mm", 0.0)))
    t = cal.template(recipe)
    template = CornerFeatures(t["u_d"], t["v_d"], t["theta_d"], t["top_angle_d"], t["right_angle_d"])
    profile = getattr(getattr(cal.part("teaching", recipe), "values", None), "profile", None)
    return CycleCalibration(
        lens=cal.lens(),
        T_H_C=cal.T_H_C(),
        laser_r=r,
        laser_l=l,
        laser_range_mm=laser_range_mm,
        nine_point=nine_point,
        taught=cal.taught(recipe),
        template=template,
        taught_profile=taught_profile_of(profile),
    )


def _sig(path: Path) -> FileSig:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)


@dataclass(frozen=True)
class _Snapshot:
    """The set as last read: which files (by identity), the set or why it was refused."""

    pointer: FileSig
    path: Path | None  # the set file the pointer named (None: no pointer, or it named nothing)
    file: FileSig
    version: int | None
    cal: CalibrationSet | None
    damage: str | None  # one line naming the file and the field; None when the set was usable


class CalibrationSetSource:
    """A CalibrationSource over a calibration store folder, read when it changes (see the module docstring)."""

    def __init__(self, store: CalibrationStore, config: CellConfig) -> None:
        self.store = store
        self.config = config
        self._snap: _Snapshot | None = None
        self._cached: dict[str | None, tuple[_Snapshot, CycleCalibration]] = {}  # by recipe slot
        self._history: dict[Path, tuple[FileSig, dict[str, Any]]] = {}
        self._lock = threading.Lock()
        self._history_lock = threading.Lock()
        self._alarms: AlarmManager | None = None
        self._audit: AsyncCellStore | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._tasks: set[asyncio.Future[Any]] = set()
        self.reads = 0  # how many times a set file was read and validated (tests, diagnostics)

    @classmethod
    def from_config(cls, config: CellConfig, *, workdir: Path) -> "CalibrationSetSource":
        return cls(CalibrationStore(store_root(config.calibration.directory, workdir)), config)

    def attach_alarms(self, alarms: AlarmManager) -> None:
        """Raise :attr:`AlarmCode.CALIBRATION_INVALID` (source ``calibration``) once for each damaged file seen.

        Call it from the event loop the alarms run on; a damage found on another thread is
        raised on that loop.
        """
        self._alarms = alarms
        self._loop = asyncio.get_running_loop()

    def attach_audit(self, store: AsyncCellStore) -> None:
        """Append ``calibration.version_changed`` to ``store``'s audit log for each version adopted that this service
        did not write (see the module docstring). Call it from the event loop the store is used on."""
        self._loop = asyncio.get_running_loop()
        self._audit = store
        self._snapshot()  # the version in use now: what a later change is told against

    # -- reading on change --------------------------------------------------------------------

    def _snapshot(self) -> _Snapshot:
        pointer = _sig(self.store.root / self.store.POINTER)
        snap = self._snap
        if snap is not None and snap.pointer == pointer and (snap.path is None or _sig(snap.path) == snap.file):
            return snap
        with self._lock:
            snap = self._snap
            if snap is not None and snap.pointer == pointer and (snap.path is None or _sig(snap.path) == snap.file):
                return snap
            new = self._read(pointer)
            self._snap = new
        if new.damage is not None and (snap is None or snap.damage != new.damage or snap.file != new.file):
            self._refused(new)
        elif new.damage is None and snap is not None and snap.damage is not None:
            log.warning("calibration set: version %s is usable again (%s)", new.version, new.path)
        if snap is not None and new.damage is None and self._written_elsewhere(snap, new):  # a damaged one is refused
            self._adopted(snap, new)
        return new

    def _written_elsewhere(self, old: _Snapshot, new: _Snapshot) -> bool:
        """``new`` is another set than ``old`` and this service did not write it (a version it committed is its own)."""
        if new.version != old.version:
            return new.version not in self.store.written  # None: the pointer removed
        return new.cal != old.cal  # the same version, edited in place (or damaged, or mended)

    def _adopted(self, old: _Snapshot, new: _Snapshot) -> None:
        """Log and audit the adoption of ``new``, which this service did not write."""
        params = adoption_params(old.version, new.version, new.cal, new.damage, self.store.root)
        log.warning("calibration set: version %s (was %s) adopted, not written by this service; written by %s", new.version,
                    old.version, params.get("written_by") or "no one the set file names")  # fmt: skip
        audit = self._audit
        if audit is None:
            return

        async def _append() -> None:
            try:
                await audit.append_audit(actor=ADOPT_ACTOR, source=ADOPT_SOURCE, action=ADOPT_ACTION, params=params)
            except Exception:  # noqa: BLE001 - the cell keeps running; the log says what was not audited
                log.exception("calibration set: the adoption of version %s could not be audited", new.version)

        self._on_loop(_append)

    def _read(self, pointer: FileSig) -> _Snapshot:
        path: Path | None = None
        file: FileSig = None
        version: int | None = None
        try:
            version = self.store.current_version()
            if version is None:
                return _Snapshot(pointer, None, None, None, None, None)
            path = self.store._path(version)  # noqa: SLF001 - the store's own naming of a version's file
            file = _sig(path)  # before reading: a change during the read is seen at the next call
            self.reads += 1
            cal = self.store.load(version)
        except (ValueError, OSError) as err:  # CalibrationSetError is a ValueError; so is a bad encoding
            return _Snapshot(pointer, path, file, version, None, self._damage_text(err, version))
        return _Snapshot(pointer, path, file, version, cal, None)

    def _damage_text(self, err: Exception, version: int | None) -> str:
        return damage_text(self.store, err, version)

    def _refused(self, snap: _Snapshot) -> None:
        assert snap.damage is not None
        log.warning("calibration set refused: %s", snap.damage)
        alarms = self._alarms
        if alarms is None:
            return
        from cellctl.domain import AlarmCode

        self._on_loop(lambda: alarms.raise_alarm(AlarmCode.CALIBRATION_INVALID, source="calibration", detail=snap.damage or ""))

    def _on_loop(self, make: Callable[[], Coroutine[Any, Any, Any]]) -> None:
        """Run ``make()`` as a task on the attached loop, from this thread or any other (nothing without a loop)."""
        loop = self._loop
        if loop is None or loop.is_closed():
            return

        def _start() -> None:
            task = loop.create_task(make())
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)

        try:
            running = asyncio.get_running_loop()
        except RuntimeError:
            running = None
        if running is loop:
            _start()
        else:
            loop.call_soon_threadsafe(_start)

    def _current(self) -> CalibrationSet | None:
        """The set in use (None before the first); raises CalibrationRefused when it is damaged."""
        snap = self._snapshot()
        if snap.damage is not None:
            raise CalibrationRefused("set", "damaged", snap.damage)
        return snap.cal

    # -- the CalibrationSource ----------------------------------------------------------------

    def _slot(self, cal: CalibrationSet, recipe: str | None) -> str | None:
        """Where ``recipe``'s own parts are read in ``cal``: by its name first (:func:`parts_of`)."""
        return parts_of(cal, recipe, self.config.default_recipe)

    def problems(self, recipe: str | None = None, *, now: datetime | None = None) -> list[str]:
        snap = self._snapshot()
        if snap.damage is not None:
            return [snap.damage]
        return check_ready(
            snap.cal, now or datetime.now(timezone.utc), recipe=recipe, first_recipe=self.config.default_recipe, config=self.config,
            store_root=self.store.root,
        )

    def recipe_problems(self, recipe: str) -> list[str]:
        """What keeps ``recipe``'s own parts (its teaching and nine-point map) from production: stale, expired,
        taught with other settings...; [] with no set or a damaged one (its cycles then fail with the set's own problem)."""
        snap = self._snapshot()
        if snap.cal is None:
            return []
        return check_ready(snap.cal, datetime.now(timezone.utc), recipe=recipe, first_recipe=self.config.default_recipe,
                           config=self.config, parts=RECIPE_PART_NAMES, store_root=self.store.root)  # fmt: skip

    def cycle_calibration(self, recipe: str | None = None) -> CycleCalibration:
        snap = self._snapshot()
        if snap.damage is not None:
            raise CalibrationRefused("set", "damaged", snap.damage)
        cal = snap.cal
        if cal is None:
            raise CalibrationRefused("set", "missing_input", "there is no calibration set; calibrate the cell first")
        slot = self._slot(cal, recipe)
        cached = self._cached.get(slot)
        if cached is None or cached[0] is not snap:
            view = self.config.for_recipe(recipe or self.config.default_recipe)
            cached = (snap, cycle_calibration_from_set(cal, view.process.align.laser_range_mm, slot))
            self._cached = {k: v for k, v in self._cached.items() if v[0] is snap} | {slot: cached}
        return cached[1]

    def summary(self, *, now: datetime | None = None) -> dict[str, Any]:
        snap = self._snapshot()
        cal = snap.cal
        if snap.damage is not None:
            return {"source": str(self.store.root), "version": snap.version, "parts": {}, "damaged": snap.damage}
        if cal is None:
            return {"source": str(self.store.root), "version": None, "parts": {}}
        parts = {}
        for name in PART_NAMES:
            p = cal.part(name)
            expires = None if p is None else expires_utc(p, self.config)
            parts[name] = None if p is None else {
                "status": p.status, "calibrated_utc": p.calibrated_utc.isoformat(),
                "expires_utc": None if expires is None else expires.astimezone(timezone.utc).isoformat(), "method": p.method,
                "quality": p.quality, "failure": p.failure,
            }  # fmt: skip
        now = now or datetime.now(timezone.utc)
        first = self.config.default_recipe
        recipes: dict[str, Any] = {}
        warnings: list[str] = []  # the parts used though dated ahead of the clock, of every recipe
        for r in self.config.process.recipes:
            lines = check_ready(cal, now, recipe=r.name, first_recipe=first, config=self.config, store_root=self.store.root,
                                warnings=warnings)  # fmt: skip
            recipes[r.name] = {"ready": not lines, "taught": cal.usable("teaching", self._slot(cal, r.name)), "problems": lines}
        return {"source": str(self.store.root), "version": cal.version, "parts": parts, "recipes": recipes,
                "warnings": list(dict.fromkeys(warnings))}

    def history(self) -> list[dict[str, Any]]:
        """Every version, oldest first; each file read once per change, a damaged one listed as such."""
        with self._history_lock:  # /calibration calls it on worker threads
            return self._history_rows()

    def _history_rows(self) -> list[dict[str, Any]]:
        rows = []
        seen: set[Path] = set()
        for v in self.store.versions():
            path = self.store._path(v)  # noqa: SLF001
            seen.add(path)
            sig = _sig(path)
            hit = self._history.get(path)
            if hit is not None and hit[0] == sig:
                rows.append(hit[1])
                continue
            try:
                row = history_row(self.store.load(v))
            except (ValueError, OSError) as err:
                row = {"version": v, "created_utc": None, "note": "", "parts": {}, "damaged": " ".join(str(err).split())}
            self._history[path] = (sig, row)
            rows.append(row)
        for gone in set(self._history) - seen:
            del self._history[gone]
        return rows

    def untaught(self, recipe: str) -> str | None:
        snap = self._snapshot()
        if snap.cal is None:  # no set yet, or a damaged one: the cycle fails with the set's own problem
            return None
        slot = self._slot(snap.cal, recipe)
        for name, what in (("teaching", "teaching"), ("pixel_map", "nine-point map")):
            part = snap.cal.part(name, slot)
            if part is None or part.status != "ok":
                state = "is missing" if part is None else f"failed ({part.failure})"
                return (f"recipe {recipe} is not taught: its {what} {state}; "
                        f"run `{command(name, recipe_named(slot, recipe, self.config.default_recipe))}`")
        owner = taught_for(snap.cal.part("teaching", slot))
        if owner not in (None, recipe):  # a set edited by hand, or written by an older cellctl
            return (f"recipe {recipe} is not taught: the teaching it finds was taught for recipe {owner}; "
                    f"run `{command('teaching', recipe)}`")
        return None

    def reference(self, recipe: str | None = None) -> dict[str, Any]:
        snap = self._snapshot()
        cal = snap.cal
        if snap.damage is not None:
            return {"source": str(self.store.root), "version": snap.version, "damaged": True}
        if cal is None:
            return {"source": str(self.store.root), "version": None}
        slot = self._slot(cal, recipe)
        parts = {name: (None if cal.part(name, slot) is None else cal.part(name, slot).id) for name in PART_NAMES}  # type: ignore[union-attr]
        return {"source": str(self.store.root), "version": cal.version, "parts": parts}

