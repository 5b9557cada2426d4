"""cellctl bench soak on a few cycles: the report's fields, and the retention's bound held on the run's disk."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cellctl.bench.soak import SoakSettings, soak_config
from cellctl.bench.sources import BenchSettingsError
from cellctl.cli import main
from cellctl.config import load_config
from cellctl.store import CellStore, CycleState

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "config" / "sim.toml"


@pytest.mark.timeout(180)
def test_five_soak_cycles_report_memory_disk_status_latency_and_a_held_bound(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out_json, work = tmp_path / "soak.json", tmp_path / "run"
    code = main([
        "--config", str(CONFIG), "bench", "soak", "--cycles", "5", "--calibration", "oracle", "--image-bound-mb", "4",
        "--status-requests", "40", "--json", str(out_json), "--workdir", str(work), "--quiet",
    ])  # fmt: skip
    text = capsys.readouterr().out
    report = json.loads(out_json.read_text())
    assert code == 0, text
    assert report["benchmark"] == "soak" and report["settings"]["cycles"] == 5
    assert report["outcomes"]["done"] == 5
    for when in ("start", "end"):
        snap = report[when]
        assert snap["rss_mb"] > 0 and snap["database_used_mb"] > 0 and snap["database_file_mb"] > 0
        lat = snap["status_ms"]
        assert lat["n"] == 40 and 0 < lat["median"] <= lat["p95"] <= lat["max"]
    assert report["start"]["cycles"] == 1 and report["end"]["cycles"] == 5
    per = report["per_cycle"]
    assert per["images_kb"] > 100 and per["database_kb"] > 0
    ret = report["retention"]
    assert ret["bound_mb"] == 4 and ret["held"] is True and ret["pruned_images"] >= 2
    assert ret["peak_images_mb"] <= 4 and ret["final_images_mb"] <= 4  # reached during the run, never passed
    assert isinstance(report["rss_growth_mb_per_100_cycles"], float)
    for phrase in ("RSS", "GET /status at start", "GET /status at end", "disk per cycle", "retention: images bound 4 MB", "held"):
        assert phrase in text

    # The figures are the run's own: its store holds the five cycles, the pruned images say so.
    with CellStore.open(work / "var" / "bench.db") as store:
        records = [store.cycle(c.id) for c in store.cycles(limit=10)]
    assert len(records) == 5 and all(r.state is CycleState.DONE for r in records)
    pruned = [i for r in records for i in r.images if i.pruned]
    assert len(pruned) == ret["pruned_images"] and all("bound of 4 MB" in (i.pruned_reason or "") for i in pruned)
    on_disk = sum(p.stat().st_size for p in (work / "var" / "images").iterdir())
    assert on_disk / 1024**2 == pytest.approx(report["end"]["images_mb"])


def test_soak_settings_and_config() -> None:
    with pytest.raises(BenchSettingsError, match="--cycles"):
        SoakSettings(cycles=1)
    with pytest.raises(BenchSettingsError, match="--image-bound-mb"):
        SoakSettings(image_bound_mb=0)
    cfg = soak_config(load_config(CONFIG), SoakSettings(cycles=10, image_bound_mb=64, calibration="oracle"), Path("/tmp/x"))
    assert cfg.store.retention.images_max_gb == pytest.approx(64 / 1024) and cfg.store.retention.enabled
    assert cfg.plc.enabled is False and cfg.calibration.source == "oracle"
