"""The versioned calibration set: what the cycle needs, how it was obtained, and whether it is usable.

One JSON document per version holds five parts (``parts``; a recipe other than the cell's first
has its own ``teaching`` and ``pixel_map`` under ``recipes``, and a teaching records the recipe it was taught
for: teaching the first moves another's out of ``parts`` under its name), each with its values, when and how it was
made (method, software, the dataset it came from), its quality figures and warnings, the ids of
the parts it was computed with, and how long it stays valid:

- ``camera``: A (``K``, 3x3), distortion ``dist`` (k1, k2, p1, p2, k3) and ``image_size`` (w, h);
- ``hand_eye``: ``T_H_C`` (4x4, mm);
- ``laser``: ``r`` (mm) and unit ``l`` in the flange frame;
- ``pixel_map``: ``affine`` (2x3, undistorted px -> workpiece-plane mm) and ``scale_mm_per_px`` s;
- ``teaching``: ``T0``, ``C_Pos_0``, ``g_Pos_0`` (4x4 in B) and the template ``u_d``, ``v_d``,
  ``theta_d`` (with the two edge angles ``top_angle_d``, ``right_angle_d``).

A part whose calibration failed is kept with ``status = "failed"`` and the reason, so the cell
refuses production until it is redone. Loading validates every field and names the one that is
wrong. :class:`CalibrationStore` keeps the history: ``set-000001.json``, ``set-000002.json``...
in one folder and a ``current`` file naming the version in use; every change writes a new
version (never edits an old one) and moves the pointer atomically. :func:`cellctl.calibration.readiness.check_ready` lists
everything that stops production: a part missing, failed, expired, dated further in the future than its
validity, or computed from a part that has since been replaced.
"""

from __future__ import annotations

import hashlib
import json
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, ValidationError
from scipy.optimize import linear_sum_assignment

from cellctl.calibration.camera import lens_from_matrix
from cellctl.calibration.set_lock import remove_stale_temps, store_lock, write_file
from cellctl.calibration.set_parts import (
    PART_MODELS,
    CalibrationSetError,
    DatasetRef,
    Parts,
    StrictRecord,
    PartRecord,
    RecipeParts,
    WallRead,
    WrittenBy,
)
from cellctl.compensate import TaughtPoses
from cellctl.config.cell import AlignConfig
from cellctl.config.loader import format_validation_errors
from cellctl.geometry.pose import Pose
from cellctl.vision.lens import Lens

FORMAT = "cellctl-calibration-set"
FORMAT_VERSION = 1
PART_NAMES = ("camera", "hand_eye", "laser", "teaching", "pixel_map")  # the order they are commissioned in
# Which parts each part is computed from: a part is stale once one of these has been replaced.
DEPENDS_ON: dict[str, tuple[str, ...]] = {
    "camera": (),
    "hand_eye": ("camera",),
    "laser": (),
    "teaching": ("camera", "hand_eye", "laser"),
    "pixel_map": ("camera", "teaching"),
}
COMMANDS = {
    "camera": "cellctl calibrate camera",
    "hand_eye": "cellctl calibrate hand-eye",
    "laser": "cellctl calibrate laser",
    "teaching": "cellctl teach",
    "pixel_map": "cellctl calibrate nine-point",
}
RECIPE_PART_NAMES = ("teaching", "pixel_map")  # each recipe has its own; the others are the cell's


def command(name: str, recipe: str | None = None) -> str:
    """The command that makes part ``name`` (of ``recipe``'s own parts, when it names one)."""
    return COMMANDS[name] + (f" --recipe {recipe}" if recipe is not None and name in RECIPE_PART_NAMES else "")


class CalibrationSet(StrictRecord):
    """One version of the calibration set (see the module docstring)."""

    format: Literal["cellctl-calibration-set"] = FORMAT
    format_version: Literal[1] = FORMAT_VERSION
    version: int = Field(ge=1)
    created_utc: datetime
    parent_version: int | None = None
    note: str = ""
    parts: Parts = Parts()
    recipes: dict[str, RecipeParts] = {}  # the own parts of each recipe but the cell's first (whose are in parts)
    written_by: WrittenBy | None = None  # a version written outside the service (a job's: its job record names who)

    def part(self, name: str, recipe: str | None = None) -> PartRecord | None:
        """Part ``name``: a recipe's own (teaching, pixel_map) when ``recipe`` names one, else the set's."""
        if name not in PART_NAMES:
            raise KeyError(f"unknown calibration part {name!r}; the parts are {', '.join(PART_NAMES)}")
        if recipe is not None and name in RECIPE_PART_NAMES:
            return getattr(self.recipes.get(recipe, RecipeParts()), name)  # type: ignore[no-any-return]
        return getattr(self.parts, name)  # type: ignore[no-any-return]

    def usable(self, name: str, recipe: str | None = None) -> bool:
        """Part ``name`` (``recipe``'s own, when it names one) is in the set and ok."""
        p = self.part(name, recipe)
        return p is not None and p.status == "ok"

    def _ok(self, name: str, recipe: str | None = None) -> Any:
        p = self.part(name, recipe)
        if p is None or p.status != "ok" or getattr(p, "values", None) is None:
            state = "missing" if p is None else f"failed ({p.failure})"
            of = f" of recipe {recipe}" if recipe is not None and name in RECIPE_PART_NAMES else ""
            raise CalibrationSetError(f"calibration part {name}{of} is {state}; run `{command(name, recipe)}`")
        return p.values  # type: ignore[attr-defined]

    # -- typed values for the cycle ----------------------------------------------------------

    def camera_matrix(self) -> NDArray[np.float64]:
        return np.asarray(self._ok("camera").K, dtype=float)

    def dist_coeffs(self) -> NDArray[np.float64]:
        return np.asarray(self._ok("camera").dist, dtype=float)

    def image_size(self) -> tuple[int, int]:
        return tuple(self._ok("camera").image_size)  # type: ignore[return-value]

    def lens(self) -> Lens:
        """The calibrated lens: A (px), distortion k1, k2, p1, p2, k3 (eq. 17) and the image size."""
        return lens_from_matrix(self.camera_matrix(), self.dist_coeffs(), self.image_size())

    def T_H_C(self) -> Pose:
        return np.asarray(self._ok("hand_eye").T_H_C, dtype=float)

    def laser_ray(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        v = self._ok("laser")
        return np.asarray(v.r, dtype=float), np.asarray(v.l, dtype=float)

    def pixel_affine(self, recipe: str | None = None) -> NDArray[np.float64]:
        return np.asarray(self._ok("pixel_map", recipe).affine, dtype=float)

    def pixel_scale(self, recipe: str | None = None) -> float:
        return float(self._ok("pixel_map", recipe).scale_mm_per_px)

    def taught(self, recipe: str | None = None) -> TaughtPoses:
        v = self._ok("teaching", recipe)
        return TaughtPoses(np.asarray(v.T0, dtype=float), np.asarray(v.C_Pos_0, dtype=float), np.asarray(v.g_Pos_0, dtype=float))

    def template(self, recipe: str | None = None) -> dict[str, float]:
        """u_d, v_d, theta_d and the two edge angles of the taught feature (ideal pixels, rad; NaN: not in view)."""
        v = self._ok("teaching", recipe)
        keys = ("u_d", "v_d", "theta_d", "top_angle_d", "right_angle_d")
        return {k: float("nan") if getattr(v, k) is None else float(getattr(v, k)) for k in keys}

    def with_part(
        self, name: str, part: PartRecord, *, version: int, created_utc: datetime, note: str = "", recipe: str | None = None,
        written_by: WrittenBy | None = None,
    ) -> "CalibrationSet":
        """A new version with ``part`` as ``name`` (of ``recipe``'s own parts when it names one), all else kept: a
        teaching written in ``parts`` first moves the one there, with its map, under the recipe it records
        (:func:`_make_room`), so teaching the first recipe never takes another's parts, whatever their order; and a
        recipe's teaching written in one place removes its earlier one, with its map, from the other, so the one
        written last is the one read whatever their dates (a clock that ran ahead, a recompute of an older capture)."""
        if not isinstance(part, PART_MODELS[name]):
            raise TypeError(f"part {name} must be a {PART_MODELS[name].__name__}, got {type(part).__name__}")
        parts, recipes = self.parts, dict(self.recipes)
        if recipe is not None and name in RECIPE_PART_NAMES:
            recipes[recipe] = recipes.get(recipe, RecipeParts()).model_copy(update={name: part})
            if name == "teaching" and taught_for(parts.teaching) == recipe:
                parts = parts.model_copy(update={"teaching": None, "pixel_map": None})
        else:
            if name == "teaching":
                new_for = taught_for(part)
                parts, recipes = _make_room(parts, recipes, new_for)
                if new_for is not None:
                    recipes.pop(new_for, None)
            parts = parts.model_copy(update={name: part})
        return CalibrationSet(
            version=version, created_utc=created_utc, parent_version=self.version, note=note, parts=parts, recipes=recipes,
            written_by=written_by,
        )


def taught_for(part: PartRecord | None) -> str | None:
    """The recipe a teaching records it was taught for (None: another part, none, or one taught before teachings did)."""
    return getattr(getattr(part, "values", None), "recipe", None)


def _make_room(parts: Parts, recipes: dict[str, RecipeParts], new_for: str | None) -> tuple[Parts, dict[str, RecipeParts]]:
    """``parts`` and ``recipes`` before a teaching for ``new_for`` is written in ``parts``: the teaching there and
    its map moved under the recipe that teaching records when that is another, and they are what that recipe reads
    (:func:`parts_of`: its own under its name older, or none), else left out. A teaching recording no recipe (taught
    before teachings recorded it: the first's then) is replaced in place, as before."""
    old = parts.teaching
    owner = taught_for(old)
    if old is None or owner is None or owner == new_for:
        return parts, recipes
    own = recipes.get(owner, RecipeParts()).teaching
    if own is None or old.calibrated_utc > own.calibrated_utc:
        recipes[owner] = RecipeParts(teaching=old, pixel_map=parts.pixel_map)
    return parts.model_copy(update={"teaching": None, "pixel_map": None}), recipes


def empty_set(created_utc: datetime) -> CalibrationSet:
    """Version 0 of nothing: the parent of the first stored set (never stored itself)."""
    return CalibrationSet.model_construct(version=0, created_utc=created_utc, parent_version=None, note="", parts=Parts())


def _set_errors(source: str, err: ValidationError) -> str:
    return format_validation_errors(
        source, err, what="the calibration set",
        unknown_field="unknown field (was the file written by a newer cellctl, or edited by hand?)",
    )  # fmt: skip


def parse_calibration_set(data: Any, source: str = "<calibration set>") -> CalibrationSet:
    """Validate a parsed JSON document; raises CalibrationSetError naming each bad field."""
    if not isinstance(data, dict):
        raise CalibrationSetError(f"{source}: the calibration set must be a JSON object, got {type(data).__name__}")
    if data.get("format") != FORMAT:
        raise CalibrationSetError(f"{source}: format must be {FORMAT!r}, got {data.get('format')!r}: not a calibration set")
    if data.get("format_version") != FORMAT_VERSION:
        raise CalibrationSetError(
            f"{source}: format_version {data.get('format_version')!r} is not supported (this cellctl reads {FORMAT_VERSION})"
        )
    try:
        return CalibrationSet.model_validate(data)
    except ValidationError as err:
        raise CalibrationSetError(_set_errors(source, err)) from None


def load_calibration_set(path: str | Path) -> CalibrationSet:
    """Read and validate a calibration set file."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CalibrationSetError(f"{p}: calibration set file not found") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as err:
        raise CalibrationSetError(f"{p}: not valid JSON ({err.msg} at line {err.lineno}, column {err.colno})") from None
    return parse_calibration_set(data, str(p))


def dump_calibration_set(cal: CalibrationSet) -> str:
    """The set as indented JSON (timestamps as UTC ISO 8601); ``written_by`` only when it names someone."""
    return cal.model_dump_json(indent=2, exclude_none=False, exclude=None if cal.written_by is not None else {"written_by"})


def part_id(name: str, values: dict[str, Any], when: datetime) -> str:
    """An id naming the part, its time and a fingerprint of its values."""
    digest = hashlib.sha256(json.dumps(values, sort_keys=True).encode("utf-8")).hexdigest()[:10]
    return f"{name}-{when.astimezone(timezone.utc):%Y%m%dT%H%M%SZ}-{digest}"


def make_part(
    name: str,
    *,
    values: dict[str, Any] | None,
    method: str,
    when: datetime,
    valid_days: float,
    quality: dict[str, Any] | None = None,
    warnings: list[str] | None = None,
    inputs: dict[str, str] | None = None,
    dataset: DatasetRef | None = None,
    software: dict[str, str] | None = None,
    failure: str | None = None,
) -> PartRecord:
    """A validated part record; ``values`` None with a ``failure`` makes a failed part."""
    if name not in PART_MODELS:
        raise KeyError(f"unknown calibration part {name!r}")
    status = "ok" if failure is None else "failed"
    pid = part_id(name, values or {"failure": failure}, when)
    try:
        return PART_MODELS[name].model_validate({
            "id": pid, "status": status, "calibrated_utc": when, "valid_days": valid_days, "method": method,
            "software": software or {}, "inputs": inputs or {}, "dataset": dataset, "quality": _jsonable(quality or {}),
            "warnings": warnings or [], "failure": failure, "values": values,
        })  # fmt: skip
    except ValidationError as err:
        raise CalibrationSetError(_set_errors(f"new {name} part", err)) from None


def _jsonable(x: Any) -> Any:
    """Quality figures as plain JSON types (numpy scalars and arrays converted)."""
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if np.isfinite(v) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.bool_,)):
        return bool(x)
    return x


def recipe_slot(recipe: str | None, first_recipe: str | None) -> str | None:
    """Where a recipe's own parts are written: None (``parts``) for the cell's first recipe, else its name (a teaching
    in ``parts`` taught for another recipe is moved under that one's name first: :meth:`CalibrationSet.with_part`)."""
    return None if recipe is None or recipe == first_recipe else recipe


def recipe_named(slot: str | None, recipe: str | None, first_recipe: str | None) -> str | None:
    """The recipe a fix's command names with ``--recipe``: the ``slot`` its parts are read at (:func:`parts_of`), or the
    recipe itself when they are read in the first's place but it is no longer first (None: the plain command, the first's)."""
    return slot if slot is not None or (recipe or first_recipe) == first_recipe else recipe


def parts_of(cal: CalibrationSet, recipe: str | None, first_recipe: str | None) -> str | None:
    """Where ``recipe``'s (None: the first's) own parts are read: under its name, unless ``parts`` holds a teaching
    recorded for it (or for none, and it is the first) and, where it has one under its name as well (a set written
    before :meth:`CalibrationSet.with_part` kept one teaching per recipe), newer than that; a teaching there of another
    recipe is never its. None: ``parts``; a name with nothing there: untaught."""
    name = recipe or first_recipe
    own, common = cal.recipes.get(name or "", RecipeParts()).teaching, cal.parts.teaching
    owner = taught_for(common)
    if name is None or (common is not None and (owner == name or (owner is None and name == first_recipe))
                        and (own is None or common.calibrated_utc > own.calibrated_utc)):
        return None
    return name


SAME_SPOT_MM = 1.0  # a taught reading place this near (mm in T0) to a configured one is the same place on the wall
HOW_READ = {"stop_and_go": "standing at process.align.spots_mm", "on_the_fly": "along process.align.sweep.path_mm"}


def wall_read_problem(taught: WallRead | None, align: AlignConfig) -> str | None:
    """Why the cycle would read the wall elsewhere or otherwise than teaching did (None: as taught, or not recorded).

    The taught plane is the reference the cycle's plane is compared with; the robot's accuracy errors
    cancel between the two only where both read the same places in the same way.
    """
    if taught is None:
        return None
    if taught.mode != align.mode:
        return (f"taught reading the wall {HOW_READ[taught.mode]} (process.align.mode = {taught.mode!r}), but the cell "
                f"now reads it {HOW_READ[align.mode]} (mode {align.mode!r})")  # fmt: skip
    was, now = np.asarray(taught.spots_mm, dtype=float), np.asarray(align.wall_spots_mm(), dtype=float)
    read = f"taught reading the wall at {len(was)} places {HOW_READ[align.mode]}"
    if was.shape != now.shape:
        return f"{read}, but that setting now names {len(now)}"
    # the places as a set (the order the robot visits them in does not change the plane): each to its nearest match
    D = np.linalg.norm(was[:, None, :] - now[None, :, :], axis=2)
    rows, cols = linear_sum_assignment(D)
    moved = D[rows, cols][D[rows, cols] > SAME_SPOT_MM]
    if moved.size == 1:
        return f"{read}, but one of them is now {moved[0]:.0f} mm from where it was taught"
    if moved.size:
        return f"{read}, but {moved.size} of them are now up to {moved.max():.0f} mm from where they were taught"
    return None


def store_root(directory: str | Path, workdir: str | Path) -> Path:
    """The store folder for the configured ``calibration.directory``: a relative one is taken from
    ``workdir`` (the service's ``--workdir``; the calibration commands take the same option)."""
    root = Path(directory)
    return root if root.is_absolute() else Path(workdir) / root


class CalibrationStore:
    """The history of calibration sets in one folder: ``set-NNNNNN.json`` files and a ``current`` pointer.

    Args:
        root: the folder (created when the first set is written).
        lock_timeout_s: how long a commit waits for another process's before it is refused (default ``LOCK_WAIT_S``).
    """

    POINTER = "current"

    def __init__(self, root: str | Path, *, lock_timeout_s: float | None = None) -> None:
        self.root = Path(root)
        self.lock_timeout_s = lock_timeout_s
        self.written: set[int] = set()  # the versions this object committed (the service tells its own from others')

    def _path(self, version: int) -> Path:
        return self.root / f"set-{version:06d}.json"

    def versions(self) -> list[int]:
        """Every stored version, oldest first."""
        if not self.root.is_dir():
            return []
        out = []
        for f in self.root.glob("set-*.json"):
            stem = f.stem.removeprefix("set-")
            if stem.isdigit():
                out.append(int(stem))
        return sorted(out)

    def current_version(self) -> int | None:
        """The version the pointer names, or None before the first set."""
        ptr = self.root / self.POINTER
        if not ptr.exists():
            return None
        name = ptr.read_text(encoding="utf-8").strip()
        stem = name.removeprefix("set-").removesuffix(".json")
        if not stem.isdigit():
            raise CalibrationSetError(f"{ptr}: does not name a calibration set file (got {name!r})")
        return int(stem)

    def load(self, version: int) -> CalibrationSet:
        cal = load_calibration_set(self._path(version))
        if cal.version != version:
            raise CalibrationSetError(f"{self._path(version)}: the file says version {cal.version}, its name {version}")
        return cal

    def current(self) -> CalibrationSet | None:
        """The set in use, validated; None when nothing was calibrated yet."""
        v = self.current_version()
        return None if v is None else self.load(v)

    def commit(
        self, name: str, part: PartRecord, *, note: str = "", now: datetime | None = None, recipe: str | None = None,
        written_by: WrittenBy | None = None,
    ) -> CalibrationSet:
        """Store a new version with ``part`` replacing ``name`` (``recipe``'s own, if it names one), make it current; locked.
        ``written_by`` names who wrote it outside the service (kept in the file)."""
        when = now or datetime.now(timezone.utc)
        self.root.mkdir(parents=True, exist_ok=True)
        with store_lock(self.root, self.lock_timeout_s):
            remove_stale_temps(self.root)
            base = self.current() or empty_set(when)
            existing = self.versions()
            version = (max(existing) if existing else 0) + 1
            new = base.with_part(name, part, version=version, created_utc=when, note=note, recipe=recipe, written_by=written_by)
            if base.version == 0:
                new = new.model_copy(update={"parent_version": None})
            path = self._path(version)
            try:
                write_file(path, dump_calibration_set(new), exclusive=True)
            except FileExistsError:
                raise CalibrationSetError(f"{path} exists already; a writer without the store's lock wrote it") from None
            self.written.add(version)  # before the pointer: a reader that sees the pointer sees this too
            write_file(self.root / self.POINTER, path.name + "\n", exclusive=False)
        return new

    def history(self) -> list[dict[str, Any]]:
        """One line per version: number, time, note and the status of each part."""
        return [history_row(self.load(v)) for v in self.versions()]


def history_row(cal: CalibrationSet) -> dict[str, Any]:
    """A version in one line: number, time, note, the status of each part and of each recipe's own."""
    def status(name: str, recipe: str | None = None) -> str | None:
        p = cal.part(name, recipe)
        return None if p is None else p.status

    return {
        "version": cal.version,
        "created_utc": cal.created_utc.isoformat(),
        "note": cal.note,
        "parts": {n: status(n) for n in PART_NAMES},
        "recipes": {r: {n: status(n, r) for n in RECIPE_PART_NAMES} for r in sorted(cal.recipes)},
    }


def damage_text(store: CalibrationStore, err: Exception, version: int | None) -> str:
    """Why the set in use (``version``) cannot be read, and how to get a usable one back."""
    text = "; ".join(line.strip().lstrip("- ") for line in str(err).splitlines() if line.strip())
    if isinstance(err, OSError) and not isinstance(err, FileNotFoundError):
        text = f"{getattr(err, 'filename', None) or store.root}: cannot be read ({err.strerror or err})"
    older = [v for v in store.versions() if version is None or v < version]
    fix = "restore the file from a backup"
    if older:
        fix += f", or point {store.root / store.POINTER} at an earlier version (e.g. set-{older[-1]:06d}.json)"
    fix += "; a new calibration builds on the set in use, so it cannot start from a damaged one"
    return f"the calibration set in use is damaged: {text}; {fix}"
