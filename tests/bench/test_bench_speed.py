"""cellctl bench speed on tiny counts: every section is measured and reported (no timed assertions)."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from cellctl.bench.sources import BenchSettingsError
from cellctl.bench.speed import SpeedSettings, format_speed, run_speed
from cellctl.bench.speed_cycle import _DeviceTimer
from cellctl.bench.speed_drivers import run_driver_bench
from cellctl.config import load_config

CONFIG = Path(__file__).resolve().parents[2] / "config" / "sim.toml"


class _FakeCamera:
    async def grab(self, *, timeout_s: float) -> SimpleNamespace:
        await asyncio.sleep(0)
        return SimpleNamespace(image=np.zeros((4, 4), np.uint8))

    async def ping(self, *, timeout_s: float) -> float:
        return 0.0


async def test_device_timer_accounts_cycle_calls_only_and_keeps_the_frames() -> None:
    account: dict[str, float] = {}
    frames: list[np.ndarray] = []
    cam = _DeviceTimer(_FakeCamera(), account, frames)
    await cam.grab(timeout_s=1.0)
    await cam.grab(timeout_s=1.0)
    await cam.ping(timeout_s=1.0)
    assert set(account) == {"grab"} and account["grab"] >= 0.0
    assert len(frames) == 2 and frames[0].shape == (4, 4)


def test_settings_are_checked() -> None:
    with pytest.raises(BenchSettingsError, match="--clients must be at least 1"):
        SpeedSettings(clients=0)
    with pytest.raises(BenchSettingsError, match="--seconds"):
        SpeedSettings(max_seconds=0)


def test_a_missing_driver_benchmark_is_reported_not_fatal() -> None:
    r = run_driver_bench("no_such_driver_pkg.bench", [])
    assert r["skipped"] == "no_such_driver_pkg.bench is not installed"


@pytest.mark.timeout(240)
def test_every_section_is_measured_and_reported() -> None:
    settings = SpeedSettings(frames=2, alignments=3, cycles=2, clients=3, requests=30, max_seconds=5.0, drivers=False)
    report = run_speed(load_config(CONFIG), settings, progress=False)
    v, a, o, s = report.vision, report.alignment, report.overhead, report.status
    assert v["frames"] == 2 and v["refused"] == 0 and v["ratio_to_canny"] == pytest.approx(v["detect_median_s"] / v["canny_median_s"])
    assert a["calls"] == 3 and a["spots"] == 6 and a["ratio_to_svd"] == pytest.approx(a["align_median_s"] / a["svd_median_s"])
    assert o["cycles"] == 2 and o["failed"] == 0 and o["time_scale"] == 0.0 and o["shots_median"] >= 2
    assert set(o["device_calls_median_s"]) >= {"move", "read", "grab"}
    assert 0.0 < o["device_median_s"] < o["cycle_median_s"]  # device time is part of the cycle time
    assert o["overhead_median_s"] is not None and set(o["split_median_s"]) == {"corner_detection", "annotated_images", "rest"}
    for phase, clients, bound in (("single", 1, 7), ("idle", 3, 30), ("busy", 3, 30)):
        assert s[phase]["requests"] > 0 and s[phase]["errors"] == 0 and s[phase]["clients"] == clients
        assert s[phase]["requests"] <= bound
    assert s["busy"]["cycles_finished_meanwhile"] >= 0
    text = format_speed(report)
    for words in ("ratio detection / Canny", "compute_alignment", "compute overhead", "idle cell", "cell running cycles",
                  "target: median overhead <= 150 ms"):  # fmt: skip
        assert words in text
    assert json.loads(json.dumps(report.as_dict()))["targets_met"] == report.targets_met()
