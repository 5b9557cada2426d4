"""GET /calibration's `warnings` lists every part used though dated ahead of the cell's clock, of every recipe: the door
window's own teaching and map, dated two hours ahead (NTP stepped the clock back since), are used for its cycles and
listed there, where the engineer is sent to look, not only logged. Truth: the dates the parts were committed with."""

from __future__ import annotations

import tomllib
from datetime import datetime, timedelta, timezone
from pathlib import Path

from calib_test_support import INPUTS, VALUES, commit_teaching

from cellctl.calibration.calibration_set import CalibrationStore, make_part
from cellctl.calibration.source import CalibrationSetSource
from cellctl.config import parse_config

ROOT = Path(__file__).resolve().parents[2]


def test_a_second_recipes_parts_dated_ahead_are_listed_in_the_warnings(tmp_path: Path) -> None:
    now = datetime.now(timezone.utc)
    store = CalibrationStore(tmp_path)
    for name in ("camera", "hand_eye", "laser"):
        cur = store.current()
        inputs = {dep: cur.part(dep).id for dep in INPUTS[name]} if cur else {}  # type: ignore[union-attr]
        store.commit(name, make_part(name, values=VALUES[name], method="test", when=now, valid_days=90.0, inputs=inputs), now=now)
    commit_teaching(store, None, "side-window", 0.0, when=now)
    ahead = now + timedelta(hours=2)
    commit_teaching(store, "door-window", "door-window", -400.0, when=ahead)
    config = parse_config(tomllib.loads((ROOT / "config" / "sim.toml").read_text()))
    summary = CalibrationSetSource(store, config).summary()
    assert [r.name for r in config.process.recipes] == ["side-window", "door-window"]
    assert summary["recipes"]["door-window"]["ready"], summary["recipes"]  # used for production
    listed = [w.split(":")[0] for w in summary["warnings"]]
    assert listed == ["teaching of recipe door-window", "pixel_map of recipe door-window"], summary["warnings"]
    assert all(f"calibrated {ahead:%Y-%m-%d %H:%M} UTC, ahead of this cell's clock" in w for w in summary["warnings"])
