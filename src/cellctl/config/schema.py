"""The root configuration model: one source of truth for every setting the cell reads."""

from __future__ import annotations

import re
import weakref
from typing import Any, Literal

import numpy as np
from pydantic import Field, PrivateAttr, ValidationError, model_validator

from cellctl.config.api import ApiConfig
from cellctl.config.calibration import CalibrationConfig
from cellctl.config.cell import ProcessConfig
from cellctl.config.devices import DevicesConfig
from cellctl.config.layout import TWIN_FIELDS_FROM_LAYOUT, LayoutConfig, opening_placement_problem
from cellctl.config.mqtt import MqttConfig
from cellctl.config.opcua import OpcUaConfig
from cellctl.config.plc import PlcConfig
from cellctl.config.reach import reach_problem
from cellctl.config.recipe import RECIPE_SECTIONS, Recipe, merge_into
from cellctl.config.sim import SimConfig, glass_size_problem
from cellctl.config.store import AlarmsConfig, PackMLConfig, StoreConfig
from cellctl.config.feature import arc_view_problem, feature_kind, gap_window_problem
from cellctl.config.types import StrictModel
from cellctl.config.vision import VisionConfig
from cellctl.inspection.flush_crossing import Opening, in_rounded_rect



TWIN_KINDS = {"laser": ("sim", "sim_keyence_lkg"), "camera": ("sim",), "robot": ("sim", "sim_abb")}
"""The device kinds of the simulated cell (``mode = "sim"``): the twin's own, or a real driver on its protocol fake."""


class _RecipeViews:
    """Each recipe's view of one configuration, and whose they are.

    The owner is held by a weak reference, not its id(): a copy may land at a freed configuration's
    address. Two are equal whatever they hold: the views follow from the fields, which pydantic compares.
    """

    __slots__ = ("owner", "views")

    def __init__(self, owner: CellConfig, views: dict[str, CellConfig]) -> None:
        self.owner = weakref.ref(owner)
        self.views = views

    def __eq__(self, other: object) -> bool:
        return other is None or isinstance(other, _RecipeViews)

    __hash__ = None  # type: ignore[assignment]


class CellConfig(StrictModel):
    """A whole cell: which devices, its nominal layout, the process, and (simulated) the twin."""

    mode: Literal["sim", "hardware"] = "sim"
    cell_id: str = Field("cell-1", min_length=1, max_length=64, pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")  # the cell's name on the line
    layout: LayoutConfig = LayoutConfig()
    process: ProcessConfig = ProcessConfig()
    devices: DevicesConfig = DevicesConfig()
    plc: PlcConfig = PlcConfig()
    opcua: OpcUaConfig = OpcUaConfig()
    mqtt: MqttConfig = MqttConfig()
    store: StoreConfig = StoreConfig()
    alarms: AlarmsConfig = AlarmsConfig()
    packml: PackMLConfig = PackMLConfig()
    vision: VisionConfig = VisionConfig()
    api: ApiConfig = ApiConfig()
    calibration: CalibrationConfig = CalibrationConfig()
    sim: SimConfig = SimConfig()
    _recipe_views: _RecipeViews | None = PrivateAttr(default=None)  # made on demand, not pickled

    def __getstate__(self) -> dict[Any, Any]:
        state = super().__getstate__()
        if state.get("__pydantic_private__"):
            state["__pydantic_private__"] = {**state["__pydantic_private__"], "_recipe_views": None}
        return state

    @model_validator(mode="before")
    @classmethod
    def _roi_is_the_camera_frame(cls, data: Any) -> Any:
        """``vision.roi`` left out: the whole frame of ``layout.camera`` (a 1920 x 1200 camera was refused over a
        2048 x 2048 default nobody wrote, and a 2448 x 2048 one never searched its right 400 px)."""
        if not isinstance(data, dict) or not isinstance(vision := data.get("vision", {}), dict) or "roi" in vision:
            return data
        cam = data.get("layout", {}).get("camera") if isinstance(data.get("layout"), dict) else None
        if not isinstance(cam, dict) or type(w := cam.get("width_px", 2048)) is not int \
                or type(h := cam.get("height_px", 2048)) is not int or min(w, h) < 64:
            return data  # an invalid size: layout.camera's own error names it
        return {**data, "vision": {**vision, "roi": {"width_px": w, "height_px": h}}}

    @model_validator(mode="before")
    @classmethod
    def _twin_stands_in_the_layout(cls, data: Any) -> Any:
        """Fill the twin's opening and reach from ``[layout]``; refuse them where they used to be."""
        if not isinstance(data, dict):
            return data
        sim = data.get("sim")
        sim = dict(sim) if isinstance(sim, dict) else ({} if sim is None else sim)
        if not isinstance(sim, dict):
            return data
        layout = data.get("layout") if isinstance(data.get("layout"), dict) else {}
        defaults = LayoutConfig()
        # An invalid [layout] table is not copied: its own error names it, a copy would repeat it as the twin's
        # (naming a [sim] section the file may not have).
        broken = {ls for ls, _ in TWIN_FIELDS_FROM_LAYOUT.values() if not _valid_layout_part(ls, layout.get(ls))}
        for (section, field), (lsection, lfield) in TWIN_FIELDS_FROM_LAYOUT.items():
            part = layout.get(lsection)
            if lsection in broken:
                continue
            value = part[lfield] if isinstance(part, dict) and lfield in part else getattr(getattr(defaults, lsection), lfield)
            given = sim.get(section)
            if given is not None and not isinstance(given, dict):
                raise ValueError(
                    f"sim.{section} = {given!r} is not a table: write it as a [sim.{section}] table of its fields "
                    "(see config/sim.toml), or leave it out"
                )
            if isinstance(given, dict) and field in given and not _same(given[field], value):
                raise ValueError(
                    f"sim.{section}.{field} belongs to the cell's nominal layout: set layout.{lsection}.{lfield} "
                    "instead (plans read it in both modes, and the twin stands there)"
                )
            sub = sim.get(section)
            sub = dict(sub) if isinstance(sub, dict) else {}
            sub[field] = value
            sim[section] = sub
        return {**data, "sim": sim}

    @model_validator(mode="after")
    def _devices_fit_the_mode(self) -> "CellConfig":
        if self.mode == "sim":
            real = [f'devices.{name}.kind = "{getattr(self.devices, name).kind}"' for name in TWIN_KINDS
                    if not getattr(self.devices, name).kind.startswith("sim")]  # fmt: skip
            if real:
                twins = ", ".join(f"{name} " + " or ".join(f'"{k}"' for k in kinds) for name, kinds in TWIN_KINDS.items())
                names = "names a real device" if len(real) == 1 else "name real devices"
                raise ValueError(
                    f"{', '.join(real)} {names}, but mode = \"sim\" (the default when mode is left out) skips every "
                    "security check of a real cell: for a real cell set mode = \"hardware\" (see "
                    f"config/hardware.example.toml; its security checks then apply), or give the twin's kinds ({twins})"
                )
        if self.mode == "hardware":
            sim = [name for name in ("laser", "camera", "robot") if getattr(self.devices, name).kind.startswith("sim")]
            if sim:
                raise ValueError(
                    f"mode = \"hardware\" but devices {sim} are simulated (kind \"sim...\"): give each its real driver "
                    "(see config/hardware.example.toml), or set mode = \"sim\""
                )
            if self.calibration.source == "oracle":
                raise ValueError('calibration.source = "oracle" exists only in the simulated cell; use "set"')
            problems = self.api.hardware_problems() + self.opcua.hardware_problems() + self.mqtt.hardware_problems()
            if problems:
                raise ValueError('mode = "hardware": ' + "; ".join(problems))
        return self

    @model_validator(mode="after")
    def _opening_before_the_robot(self) -> "CellConfig":
        """The opening's wall faces the robot, and the robot reaches the whole opening and the poses it needs: the
        shooting pose, the laser's wall readings, the install (every recipe's view too, named by its recipe)."""
        problem = opening_placement_problem(self.layout) or reach_problem(self)
        if problem is not None:
            raise ValueError(problem)
        return self

    @model_validator(mode="after")
    def _roi_in_the_image(self) -> "CellConfig":
        cam = self.layout.camera
        self.vision.roi.check_inside(cam.width_px, cam.height_px)
        if self.mode == "sim":
            real = self.sim.camera.intrinsics
            if (real.width_px, real.height_px) != (cam.width_px, cam.height_px):
                raise ValueError(
                    f"sim.camera.intrinsics is {real.width_px} x {real.height_px} px but layout.camera says "
                    f"{cam.width_px} x {cam.height_px} px: the twin's camera must have the size of the cell's camera"
                )
        return self

    @model_validator(mode="after")
    def _corner_visible(self) -> "CellConfig":
        """The corner method where both edges run straight in view beside the corner, else the arc must be."""
        if feature_kind(self) == "arc":
            problem = arc_view_problem(self)
            if problem is not None:
                r = self.layout.opening.corner_radius_mm
                raise ValueError(f"layout.opening.corner_radius_mm = {r:g} makes the arc the feature, but {problem}")
        return self

    @model_validator(mode="after")
    def _gap_window_in_the_image(self) -> "CellConfig":
        """The inspection's window along each edge (``[vision.gap]``) keeps the pixels it measures on in the image."""
        problem = gap_window_problem(self)
        if problem is not None:
            raise ValueError(problem)
        return self

    @model_validator(mode="after")
    def _laser_in_the_heads_range(self) -> "CellConfig":
        """The alignment's standoff and accepted range lie within the sensor head's measuring range."""
        problem = laser_range_problem(self.process.align.laser_standoff_mm, self.process.align.laser_range_mm,
                                      self.layout.laser_mount.range_min_mm, self.layout.laser_mount.range_max_mm)  # fmt: skip
        if problem is not None:
            raise ValueError(problem)
        return self

    @model_validator(mode="after")
    def _servers_on_their_own_ports(self) -> "CellConfig":
        """The API, the PLC's and the OPC UA server (those enabled) cannot listen on one port of one address."""
        listening = [("api", self.api.host, self.api.port)]
        listening += [(name, s.host, s.port) for name, s in (("plc", self.plc), ("opcua", self.opcua)) if s.enabled]
        for k, (a, host_a, port_a) in enumerate(listening):
            for b, host_b, port_b in listening[k + 1:]:
                if port_a == port_b != 0 and _same_address(host_a, host_b):
                    raise ValueError(
                        f"{a}.port and {b}.port are both {port_a} on one address ({a}.host = {host_a!r}, "
                        f"{b}.host = {host_b!r}; 0.0.0.0 or '' is every address): the second server could not "
                        f"listen; give each its own port (0: any free one)"
                    )
        return self

    @model_validator(mode="after")
    def _process_on_its_opening(self) -> "CellConfig":
        """The process knows the opening's outline (its flush sweep tells glass from wall by it)."""
        o = self.layout.opening
        process = self.process.on_opening(Opening(o.width_mm, o.height_mm, o.corner_radius_mm))
        if process is not self.process:  # a process another configuration holds: this one's own copy (frozen: set in place)
            self.__dict__["process"] = process
        return self

    @model_validator(mode="after")
    def _spots_fit_the_opening(self) -> "CellConfig":
        """The alignment's wall spots (or sweep) on the wall; each flush spot's glass reading on the glass, its
        wall reading on the wall; the flush sweep across this opening's edges (every recipe's view runs it too, with
        its own opening, spots and path)."""
        o = self.layout.opening
        problem = (align_spots_problem(self) or spots_problem(self)
                   or self.process.flush_sweep_problem(Opening(o.width_mm, o.height_mm, o.corner_radius_mm)))  # fmt: skip
        if problem is not None:
            raise ValueError(problem)
        return self

    @model_validator(mode="after")
    def _twin_glass_fits_the_opening(self) -> "CellConfig":
        """The simulated cell's glass fits its opening (a recipe's view: the recipe's glass and opening)."""
        problem = glass_size_problem(self.sim.glass, self.sim.world) if self.mode == "sim" else None
        if problem is not None:
            raise ValueError(problem)
        return self

    @model_validator(mode="after")
    def _recipes_make_valid_cells(self) -> "CellConfig":
        """Each recipe's sections checked as the tables they replace (a bad field names its recipe)."""
        self._recipe_views = _RecipeViews(self, self._make_recipe_views())
        return self

    def _make_recipe_views(self) -> dict[str, "CellConfig"]:
        views: dict[str, CellConfig] = {}
        problems: list[str] = []
        for k, recipe in enumerate(self.process.recipes):
            if not recipe.overrides():
                continue
            try:
                views[recipe.name] = CellConfig.model_validate(self._recipe_data(recipe))
            except ValidationError as err:
                problems += [_recipe_problem(k, recipe, e) for e in err.errors() if not _twin_copy(recipe, e)]
        if problems:
            raise ValueError("recipe settings that make no valid cell:\n    - " + "\n    - ".join(problems))
        return views

    def _recipe_data(self, recipe: Recipe) -> dict[str, Any]:
        """This configuration as data with the recipe's sections set in, every recipe listed bare."""
        data = self.model_dump(mode="python", exclude_defaults=False)
        for section, field in TWIN_FIELDS_FROM_LAYOUT:  # filled again from [layout]
            data["sim"][section].pop(field, None)
        data["process"]["recipes"] = [r.bare() for r in self.process.recipes]
        for name, fields in recipe.overrides().items():
            merge_into(data, RECIPE_SECTIONS[name], fields)
        return data

    def for_recipe(self, name: str) -> "CellConfig":
        """The configuration a cycle of recipe ``name`` runs with: the cell's, with the recipe's sections set in.

        Its own list of recipes is bare (numbers and names); ask this configuration for another recipe.
        """
        if name not in {r.name for r in self.process.recipes}:
            known = ", ".join(r.name for r in self.process.recipes)
            raise KeyError(f"no recipe {name!r} in [[process.recipes]] (the recipes are: {known})")
        if self._recipe_views is None or self._recipe_views.owner() is not self:  # a model_copy: its own views, made once
            self._recipe_views = _RecipeViews(self, self._make_recipe_views())
        return self._recipe_views.views.get(name, self)

    @property
    def default_recipe(self) -> str:
        """The first recipe's name: a cycle that names none is one of these."""
        return self.process.recipes[0].name


def _valid_layout_part(name: str, part: Any) -> bool:
    """Whether ``[layout.<name>]`` as given (None: left out) is a valid table of its own."""
    if not isinstance(part, dict):
        return True  # left out (the defaults), or not a table: [layout]'s own check says so
    try:
        LayoutConfig.model_fields[name].annotation.model_validate(part)  # type: ignore[union-attr]
    except ValidationError:
        return False
    return True


def _recipe_problem(index: int, recipe: Recipe, error: Any) -> str:
    """One field error of a recipe's view, named where the recipe sets it (else where the cell does)."""
    loc = tuple(str(p) for p in error["loc"] if not str(p).startswith("function-after"))
    msg = str(error["msg"]).removeprefix("Value error, ")
    for name, path in RECIPE_SECTIONS.items():  # a rule across tables whose message starts with its field
        table = ".".join(path)
        if not loc and msg.startswith(table + "."):
            own, field = getattr(recipe, name), re.match(r"\w*", msg[len(table) + 1:]).group()  # type: ignore[union-attr]
            whose = "" if field in own else (
                f" (the cell's [{table}]: this recipe sets no [process.recipes.{name}] of its own; give it one)" if not own
                else f" (the cell's {table}.{field}: this recipe's [process.recipes.{name}] sets no {field}; give it its own)")
            return f"process.recipes[{index}] ({recipe.name}): {name}{msg[len(table):]}{whose}"
    if error["type"] == "extra_forbidden":
        msg = "unknown field; check its spelling against the table it replaces"
    where = ".".join(loc) or "(top level)"
    for name, path in RECIPE_SECTIONS.items():
        if loc[: len(path)] == path and getattr(recipe, name):
            where = f"{name}." + ".".join(loc[len(path):]) if len(loc) > len(path) else name
            break
    return f"process.recipes[{index}] ({recipe.name}): {where}: {msg}"


def _in_rounded_rect(x: float, y: float, left: float, right: float, top: float, bottom: float, radius: float) -> bool:
    """Whether (x, y) (T, mm; y down) lies strictly inside the rectangle with corners rounded by ``radius`` (mm)."""
    return bool(in_rounded_rect((x, y), left, right, top, bottom, radius)[0])


def align_spots_problem(config: CellConfig) -> str | None:
    """Why a place where the alignment reads the wall (a spot, or a point of the sweep's path) lies in the opening
    of ``layout.opening`` (T, mm), or None."""
    o, align = config.layout.opening, config.process.align
    stops, spots = align.wall_stops(), align.wall_spots_mm()
    for k in sorted(range(len(spots)), key=lambda k: bool(stops) and k not in stops):  # a sweep's corners first
        x, y = spots[k]
        if not _in_rounded_rect(x, y, -o.width_mm, 0.0, 0.0, o.height_mm, o.corner_radius_mm):
            continue
        where = (f"{align.wall_setting()}[{k}] [{x:g}, {y:g}] lies" if not stops else
                 f"{align.wall_setting()}[{stops.index(k)}] [{x:g}, {y:g}] lies" if k in stops else
                 f"{align.wall_setting()}: the leg from corner {_leg_of(stops, k)} to {_leg_of(stops, k) + 1} passes "
                 f"[{x:.0f}, {y:.0f}],")  # fmt: skip
        return (f"{where} in the opening ({o.width_mm:g} x {o.height_mm:g} mm, corner radius {o.corner_radius_mm:g}: "
                f"x in [{-o.width_mm:g}, 0], y in [0, {o.height_mm:g}] of T), where the laser reads no wall and the "
                "cycle would fail; move it onto the wall (x > 0 or y < 0 of T, or beyond the opening's far sides)")
    return None


def _leg_of(stops: tuple[int, ...], k: int) -> int:
    """The leg (from corner j to j + 1) of a sweep's path that point ``k`` along it lies on."""
    return max(j for j, s in enumerate(stops) if s < k)


def spots_problem(config: CellConfig) -> str | None:
    """Why a flush spot is off the glass or off the wall for the opening of ``layout.opening`` (None: all fit).

    The glass is the opening inset by ``process.inspect.nominal_gap_mm`` (corner radius less the gap); T: x right,
    y down from the opening's upper-right corner, the opening x in [-width, 0], y in [0, height]."""
    o, gap = config.layout.opening, config.process.inspect.nominal_gap_mm
    w, h, r = o.width_mm, o.height_mm, o.corner_radius_mm
    size = f"the opening {w:g} x {h:g} mm, corner radius {r:g}"
    glass = (f"the glass ({size}, less process.inspect.nominal_gap_mm = {gap:g}: x in ({-w + gap:g}, {-gap:g}), "
             f"y in ({gap:g}, {h - gap:g}), corners rounded {max(r - gap, 0.0):g} mm)")  # fmt: skip
    found: list[str] = []
    for k, spot in enumerate(config.process.inspect.flush_spots):
        (gx, gy), (wx, wy) = spot.glass_mm, spot.wall_mm
        if not _in_rounded_rect(gx, gy, -w + gap, -gap, gap, h - gap, r - gap):
            on = -w + gap < gx < -gap and gap < gy < h - gap
            found.append(f"process.inspect.flush_spots[{k}].glass_mm [{gx:g}, {gy:g}] is "
                         f"{'beyond the corner arc of' if on else 'off'} {glass}; move it onto the glass")  # fmt: skip
        elif _in_rounded_rect(wx, wy, -w, 0.0, 0.0, h, r):
            found.append(f"process.inspect.flush_spots[{k}].wall_mm [{wx:g}, {wy:g}] lies in the opening ({size}); "
                         "move it onto the wall just across the edge from its glass spot")
    if not found:
        return None
    more = f" ({len(found) - 1} more spot(s) do not fit either)" if len(found) > 1 else ""
    return found[0] + more


def _twin_copy(recipe: Recipe, error: Any) -> bool:
    """An error of the twin's copy of the recipe's opening (``sim.world``): the opening's own error says it."""
    return bool(recipe.opening) and tuple(error["loc"][:2]) == ("sim", "world")


EVERY_ADDRESS = frozenset({"", "0.0.0.0", "::", "[::]", "*"})


def _same_address(a: str, b: str) -> bool:
    """Whether servers bound to hosts ``a`` and ``b`` share an address (every address includes each one)."""
    a, b = ("127.0.0.1" if h == "localhost" else h for h in (a.strip().lower(), b.strip().lower()))
    return a == b or a in EVERY_ADDRESS or b in EVERY_ADDRESS


def laser_range_problem(standoff_mm: float, range_mm: tuple[float, float], head_min_mm: float, head_max_mm: float) -> str | None:
    """Why process.align's standoff or accepted range does not fit the head's range ([layout.laser_mount]), or None."""
    head = (f"the sensor head's measuring range, layout.laser_mount.range_min_mm = {head_min_mm:g} "
            f"to range_max_mm = {head_max_mm:g}")
    if not head_min_mm <= standoff_mm <= head_max_mm:
        return (f"process.align.laser_standoff_mm = {standoff_mm:g} lies outside {head}: the laser reads nothing there; "
                "set the standoff inside the head's range (its middle is best), or correct [layout.laser_mount] "
                "to the head fitted")
    lo, hi = range_mm
    if lo < head_min_mm or hi > head_max_mm:
        return (f"process.align.laser_range_mm = [{lo:g}, {hi:g}] extends beyond {head}: the head gives no reading "
                "there; keep laser_range_mm within the head's range, or correct [layout.laser_mount] to the head fitted")
    return None


def _same(a: Any, b: Any) -> bool:
    """Equal numbers or vectors (a configuration dumped and read back repeats the layout's values)."""
    try:
        return bool(np.allclose(np.asarray(a, dtype=float), np.asarray(b, dtype=float), rtol=0.0, atol=1e-9))
    except (TypeError, ValueError):
        return a == b
