"""The simulated cell's error sources, their off-switches, and the configuration of a benchmark run.

Each source is switched off by setting the twin's configuration fields named in ``config/sim.toml``
to zero (or false); every source draws from its own random stream, so switching one off leaves
the draws of all the others unchanged and runs with different switches compare like with like.
The calibration is a source too: ``"data"`` computes the calibration set from simulated data (the
production way, with the calibrations' own errors), ``"oracle"`` hands the cycle the twin's true
mountings (taught by the paper's procedure in the twin).
"""

from __future__ import annotations

from collections.abc import Iterator

import tempfile

import contextlib

import importlib.util
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from cellctl.config import CellConfig, parse_config

CalibrationMode = Literal["data", "oracle"]
CALIBRATION_MODES: tuple[CalibrationMode, ...] = ("data", "oracle")
# "twin": the twin's in-process devices (kind = "sim"); "config": the devices the configuration names
# (in config/sim.toml the real drivers against their protocol fakes).
DevicesMode = Literal["twin", "config"]
DEVICES_MODES: tuple[DevicesMode, ...] = ("twin", "config")
CALIBRATION_SOURCE = "calibration"  # the budget's name for "calibration from data instead of the truth"


@dataclass(frozen=True)
class ErrorSource:
    """One error source of the twin and the configuration fields that switch it off.

    Attributes:
        name: the switch's name on the command line (``--off NAME``).
        description: what the source is, for reports.
        off_fields: dotted configuration path -> the value that removes the source.
    """

    name: str
    description: str
    off_fields: Mapping[str, Any]
    data_calibration_only: bool = False  # it acts through the calibration from data (none with the oracle)


ERROR_SOURCES: Mapping[str, ErrorSource] = {
    s.name: s
    for s in (
        ErrorSource("laser_noise", "LK-G repeatability noise, per reading", {"sim.laser.noise_mm": 0.0}),
        ErrorSource(
            "laser_linearity", "LK-G linearity, +-0.02 % FS (a fixed curve)", {"sim.laser.linearity_fraction_fs": 0.0}
        ),
        ErrorSource(
            "robot_repeatability",
            "robot pose repeatability (ISO 9283 RP 0.1 mm), per move",
            {"sim.robot.repeatability_mm": 0.0, "sim.robot.repeatability_orientation_deg": 0.0},
        ),
        ErrorSource(
            "robot_accuracy",
            "robot absolute accuracy (smooth pose-dependent field)",
            {"sim.robot.absolute_accuracy_mm": 0.0, "sim.robot.absolute_accuracy_deg": 0.0},
        ),
        ErrorSource(
            "image_noise",
            "camera read and shot noise",
            {"sim.camera.render.read_noise_dn": 0.0, "sim.camera.render.shot_noise": False},
        ),
        ErrorSource(
            "teach_hand_guiding",
            "operator's hand-guiding error in the taught install pose g_Pos_0",
            {
                "sim.operator.hand_guiding_position_mm": 0.0,
                "sim.operator.hand_guiding_orientation_deg": 0.0,
            },
            data_calibration_only=True,
        ),
    )
}


class BenchSettingsError(ValueError):
    """A benchmark option cannot be used; the message names the option and what to do."""


def parse_off(text: str | None) -> frozenset[str]:
    """``--off laser_noise,robot_repeatability`` (or ``all``) -> the set of source names."""
    if text is None or not text.strip():
        return frozenset()
    names = {n.strip() for n in text.split(",") if n.strip()}
    if "all" in names:
        return frozenset(ERROR_SOURCES)
    unknown = sorted(names - set(ERROR_SOURCES))
    if unknown:
        raise BenchSettingsError(
            f"--off: unknown error source(s) {', '.join(unknown)}; known: {', '.join(ERROR_SOURCES)} (or all)"
        )
    return frozenset(names)


def data_calibration_available() -> bool:
    """Whether the calibration set built from simulated data can be used (cellctl.calibration.source)."""
    try:
        return importlib.util.find_spec("cellctl.calibration.source") is not None
    except ImportError:
        return False


def _set_path(data: dict[str, Any], dotted: str, value: Any) -> None:
    node = data
    parts = dotted.split(".")
    for part in parts[:-1]:
        node = node.setdefault(part, {})
    if parts[-1] not in node:
        raise BenchSettingsError(f"configuration field {dotted} does not exist (cannot switch it)")
    node[parts[-1]] = value


def run_config(
    base: CellConfig,
    *,
    workdir: Path,
    seed: int,
    off: Iterable[str] = (),
    calibration: CalibrationMode = "oracle",
    time_scale: float | None = None,
    devices: DevicesMode = "twin",
) -> CellConfig:
    """The configuration of one benchmark run of the simulated cell.

    ``base`` with: the sources in ``off`` switched off, the seed, the calibration source, the
    store and the calibration set inside ``workdir``, no PLC server (the benchmark drives the
    orchestrator, as the PLC link and the REST API do), and with ``devices = "twin"`` the twin's
    in-process laser, camera and robot.
    """
    if base.mode != "sim":
        raise BenchSettingsError(
            f"the benchmarks run on the simulated cell; the configuration has mode = {base.mode!r} "
            "(use config/sim.toml or a copy of it)"
        )
    if calibration not in CALIBRATION_MODES:
        raise BenchSettingsError(f"--calibration must be one of {', '.join(CALIBRATION_MODES)}, got {calibration!r}")
    if devices not in DEVICES_MODES:
        raise BenchSettingsError(f"--devices must be one of {', '.join(DEVICES_MODES)}, got {devices!r}")
    if seed < 0:
        raise BenchSettingsError(f"--seed must be a non-negative integer, got {seed}")
    data = base.model_dump(mode="json")
    for name in off:
        if name not in ERROR_SOURCES:
            raise BenchSettingsError(f"unknown error source {name!r}; known: {', '.join(ERROR_SOURCES)}")
        for path, value in ERROR_SOURCES[name].off_fields.items():
            _set_path(data, path, value)
    _set_path(data, "sim.seed", int(seed))
    if devices == "twin":
        for name in ("laser", "camera", "robot"):
            _set_path(data, f"devices.{name}", {"kind": "sim"})
    if time_scale is not None:
        _set_path(data, "sim.time_scale", float(time_scale))
    _set_path(data, "plc.enabled", False)
    _set_path(data, "opcua.enabled", False)
    _set_path(data, "store.path", str((workdir / "var" / "bench.db").resolve()))
    _set_path(data, "calibration.source", "set" if calibration == "data" else "oracle")
    _set_path(data, "calibration.directory", str((workdir / "var" / "calibration").resolve()))
    _set_path(data, "calibration.auto_calibrate_in_sim", True)
    return parse_config(data, "benchmark run configuration")


@contextlib.contextmanager
def run_workdir(keep: Path | None, prefix: str = "cellctl-bench-") -> Iterator[Path]:
    """Where a benchmark run keeps its store and images: ``keep`` (new or empty), else a temporary folder."""
    if keep is not None:
        keep.mkdir(parents=True, exist_ok=True)
        if any(keep.iterdir()):
            raise BenchSettingsError(f"--workdir {keep} is not empty; give a new or empty folder (the run's store goes there)")
        yield keep
        return
    with tempfile.TemporaryDirectory(prefix=prefix) as tmp:
        yield Path(tmp)
