"""Parts calibrated while the cell's clock was ahead (a PC whose RTC keeps local time, or not yet synced while
commissioning ran) keep the cell in production after NTP steps the clock back: a part dated ahead of the clock by less
than a day is used, with a warning in the log naming it, and still expires on its date + valid_days; one dated a day or
more ahead (within its validity too: its true age cannot be told, it would count that much longer) is refused as
calibrated in the future, naming the part, its date and the fix.

The wall clock is stepped in-process (clock_step_support: cellctl's datetime and time.time, monotonic untouched); the
parts are the twin's truth, stamped by the stepped clock as the jobs stamp them. Scored over REST with httpx (POST
/cycle runs or is refused with 409) and by the dates of the store's files read with json."""

from __future__ import annotations

import asyncio
import json
import logging
import tomllib
from collections.abc import Iterator
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import httpx
import pytest
from service_test_support import AUTH, ROOT, api_client, running_service, to_execute, truth_values

import clock_step_support as clock
from cellctl.calibration.calibration_set import DEPENDS_ON, CalibrationStore, make_part
from cellctl.config import CellConfig, parse_config

pytestmark = pytest.mark.timeout(300)
NAMES = ("camera", "hand_eye", "laser", "teaching", "pixel_map")
VALID_DAYS = 90.0


def _config(cal_dir: Path | None) -> CellConfig:
    """config/sim.toml with the side window only, PLC and OPC UA off: the oracle's calibration, or the set at ``cal_dir``."""
    data = tomllib.loads((ROOT / "config" / "sim.toml").read_text())
    data["calibration"] |= {"source": "oracle"} if cal_dir is None else {
        "source": "set", "directory": str(cal_dir), "auto_calibrate_in_sim": False, "max_age_days": VALID_DAYS}  # fmt: skip
    data["process"]["recipes"] = data["process"]["recipes"][:1]
    data["opcua"]["enabled"] = False
    data["plc"]["enabled"] = False
    data["api"]["port"] = 0
    return parse_config(data, "sim.toml (test)")


@pytest.fixture
def stepped() -> Iterator[None]:
    clock.install()
    try:
        yield
    finally:
        clock.uninstall()


async def _cycle(client: httpx.AsyncClient, key: str) -> httpx.Response:
    return await client.post("/cycle?wait=true&timeout_s=90", json={"recipe": "side-window", "part_id": key},
                             headers={**AUTH, "Idempotency-Key": key})  # fmt: skip


def _commit_truth(store: CalibrationStore, cal: Any, when: datetime) -> None:
    """The twin's truth of the side window, every part calibrated at ``when`` and valid VALID_DAYS."""
    values, m = truth_values(cal, "side-window"), cal.nine_point
    for name in NAMES:
        cur = store.current()
        inputs = {dep: cur.part(dep).id for dep in DEPENDS_ON[name]} if cur else {}  # type: ignore[union-attr]
        q = {"map_residuals_mm": m.residuals_mm.tolist(), "map_rms_mm": m.rms_mm, "map_max_mm": m.max_mm} if name == "pixel_map" else None
        store.commit(name, make_part(name, values=values[name], method="twin truth", when=when, valid_days=VALID_DAYS,
                                     inputs=inputs, quality=q), now=when)  # fmt: skip


async def test_parts_calibrated_an_hour_ahead_run_after_ntp_steps_the_clock_back_and_expire_as_dated(
    tmp_path: Path, stepped: None, caplog: pytest.LogCaptureFixture
) -> None:
    async with running_service(tmp_path / "oracle", _config(None)) as oracle:
        truth = await asyncio.to_thread(oracle.orchestrator.calibration.cycle_calibration)
    clock.step(+3600.0)  # the PC runs an hour ahead while the cell is commissioned
    store = CalibrationStore(tmp_path / "calibration")
    _commit_truth(store, truth, clock.wall_now())
    clock.step(-3600.0)  # NTP steps the clock back: it is right now
    files = json.loads((store.root / (store.root / "current").read_text().strip()).read_text())["parts"]
    dated = {name: datetime.fromisoformat(p["calibrated_utc"]) for name, p in files.items()}
    assert all(timedelta(minutes=59) < d - datetime.now(timezone.utc) <= timedelta(hours=1) for d in dated.values()), dated
    async with running_service(tmp_path / "cell", _config(store.root)) as service, api_client(service) as client:
        await to_execute(client)
        with caplog.at_level(logging.WARNING, logger="cellctl"):
            r = await _cycle(client, "G-1")
            status = (await client.get("/status")).json()["calibration"]
        body = r.json()
        assert r.status_code == 200 and body["state"] == "done", (r.status_code, body.get("detail") or body.get("error"))
        assert status["problems"] == [] and status["recipes"]["side-window"]["ready"], status
        said = [rec.getMessage() for rec in caplog.records if rec.levelno == logging.WARNING]
        for name in NAMES:  # a warning, naming the part, its date and the clock
            line = f"calibration: {name}: calibrated {dated[name]:%Y-%m-%d %H:%M} UTC, ahead of this cell's clock"
            assert sum(m.startswith(line) for m in said) == 1, (name, said)
        assert all("check the clock" in m for m in said if "ahead of this cell's clock" in m), said
        shown = (await client.get("/calibration")).json()["current"]["warnings"]  # and shown where the engineer looks
        assert sorted(w.split(":")[0] for w in shown) == sorted(NAMES), shown

        clock.step(-10 * 86400.0)  # a clock set back ten days, well within the parts' validity: refused all the same
        r = await _cycle(client, "G-2")
        problems = (await client.get("/status")).json()["calibration"]["problems"]
        assert r.status_code == 409 and "teaching: calibrated in the future" in r.json()["detail"], r.text
        for name in NAMES:
            line = f"{name}: calibrated in the future ({dated[name]:%Y-%m-%d %H:%M} UTC), 10.0 days ahead of this cell's clock"
            assert any(p.startswith(line) and "check the clock" in p for p in problems), (name, problems)

        # on the clock, a part dated ahead lives no longer than valid_days from its date
        clock.reset()
        clock.step((dated["camera"] + timedelta(days=VALID_DAYS, minutes=1) - datetime.now(timezone.utc)).total_seconds())
        r = await _cycle(client, "G-3")
        expires = dated["camera"] + timedelta(days=VALID_DAYS)
        assert r.status_code == 409 and f"teaching: expired on {expires:%Y-%m-%d %H:%M} UTC" in r.json()["detail"], r.text
        problems = (await client.get("/status")).json()["calibration"]["problems"]
        assert all(any(p.startswith(f"{name}: expired on {expires:%Y-%m-%d %H:%M} UTC") for p in problems) for name in NAMES), problems
        clock.step(-2 * 60.0)  # a minute before: it still runs
        r = await _cycle(client, "G-4")
        assert r.status_code == 200 and r.json()["state"] == "done", r.text
