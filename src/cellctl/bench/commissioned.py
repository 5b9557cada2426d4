"""Each simulated cell commissioned once from its own simulated data, its calibration set kept for its runs.

The simulated cell's service commissions itself (camera, hand-eye, laser, teaching, nine-point as
jobs on its own twin, the simulated operator answering), exactly as ``--calibration data`` does in
one run; the set files (not the datasets) are kept in ``cache/seed-S/calibration`` with a
fingerprint of what they depend on, and copied into every run of that cell.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import shutil
from dataclasses import dataclass
from pathlib import Path

from cellctl.bench.accuracy import prepare_calibration
from cellctl.bench.sources import DevicesMode, run_config, run_workdir
from cellctl.config import CellConfig

CACHE_INFO = "bench-cache.json"


def _fingerprint(config: CellConfig, seed: int, off: tuple[str, ...]) -> str:
    """What a cached calibration set depends on: the whole configuration (but where things are stored and
    served, and the devices' wiring), the seed and the sources off. Any other change commissions again."""
    data = config.model_dump(mode="json")
    for key in ("store", "api", "plc", "devices"):
        data.pop(key, None)
    data["calibration"] = {
        k: v for k, v in data.get("calibration", {}).items() if k not in ("directory", "source", "auto_calibrate_in_sim")
    }
    data.setdefault("sim", {})["seed"] = seed
    key = {"config": data, "off": sorted(off)}
    return hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()


def copy_set(src: Path, dst: Path) -> None:
    """The set files and the ``current`` pointer (the datasets they came from stay behind)."""
    dst.mkdir(parents=True, exist_ok=True)
    for f in list(src.glob("set-*.json")) + [src / "current"]:
        shutil.copy2(f, dst / f.name)


def _set_usable(directory: Path) -> bool:
    from datetime import datetime, timezone

    from cellctl.calibration.calibration_set import CalibrationStore
    from cellctl.calibration.readiness import check_ready

    try:
        return not check_ready(CalibrationStore(directory).current(), datetime.now(timezone.utc))
    except (ValueError, OSError):
        return False


async def _commission(config: CellConfig, workdir: Path, timeout_s: float) -> float:
    from cellctl.service import build_service

    service = await build_service(config, workdir=workdir)
    await service.start()
    try:
        return await prepare_calibration(service, timeout_s)
    finally:
        await service.stop()


@dataclass(frozen=True)
class Commissioned:
    """A cell's calibration set, commissioned from its own simulated data, and how it was got."""

    seed: int
    directory: Path
    seconds: float
    cached: bool


def commission_cell(
    base: CellConfig,
    seed: int,
    cache: Path,
    *,
    off: tuple[str, ...] = (),
    time_scale: float | None = None,
    devices: DevicesMode = "twin",
    timeout_s: float = 3600.0,
) -> Commissioned:
    """The calibration set of the cell of ``seed``, commissioned by its service's jobs on its own twin.

    Kept in ``cache/seed-S`` (set files and pointer) with what it depends on; a later run with the
    same twin, procedures and sources off takes it from there instead of commissioning again.
    """
    where = cache / f"seed-{seed}"
    fp = _fingerprint(base, seed, off)
    info = where / CACHE_INFO
    if info.is_file() and _set_usable(where / "calibration"):
        try:
            if json.loads(info.read_text(encoding="utf-8")).get("fingerprint") == fp:
                return Commissioned(seed, where / "calibration", 0.0, True)
        except ValueError:
            pass
    if where.exists():
        shutil.rmtree(where)
    with run_workdir(None, "cellctl-bench-commission-") as wd:
        config = run_config(base, workdir=wd, seed=seed, off=off, calibration="data", time_scale=time_scale, devices=devices)
        seconds = asyncio.run(_commission(config, wd, timeout_s))
        copy_set(Path(config.calibration.directory), where / "calibration")
    info.write_text(json.dumps({"seed": seed, "off": sorted(off), "fingerprint": fp, "seconds": seconds}) + "\n", encoding="utf-8")
    return Commissioned(seed, where / "calibration", seconds, False)
