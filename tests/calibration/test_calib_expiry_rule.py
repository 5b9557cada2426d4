"""A calibration part expires at calibrated_utc + the shorter of the validity recorded with it (``valid_days``, the
``calibration.max_age_days`` in force when it was calibrated) and the running configuration's
``calibration.max_age_days``: lowering the limit applies at once, raising it applies to parts calibrated after.

``GET /calibration`` gives each part's ``expires_utc`` (null for a failed part), and the service keeps the cell from
production by the same date. The peers: the calibrated_utc and valid_days of the store's file as json reads them, and
the limits the tests put in the configuration; the answers through httpx.
"""

from __future__ import annotations

import json
import tomllib
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import httpx
from calib_test_support import INPUTS, VALUES
from service_test_support import AUTH, ROOT, api_client, running_service, to_execute

from cellctl.calibration.calibration_set import CalibrationStore, make_part
from cellctl.config import CellConfig, parse_config

NAMES = ("camera", "hand_eye", "laser", "teaching", "pixel_map")


def cell_config(cal_dir: Path, max_age_days: float) -> CellConfig:
    """config/sim.toml with the calibration set at ``cal_dir`` and ``calibration.max_age_days``; PLC and OPC UA off."""
    data = tomllib.loads((ROOT / "config" / "sim.toml").read_text())
    data["calibration"] |= {"source": "set", "directory": str(cal_dir), "auto_calibrate_in_sim": False,
                            "max_age_days": max_age_days}  # fmt: skip
    data["opcua"]["enabled"] = False
    data["plc"]["enabled"] = False
    data["api"]["port"] = 0
    return parse_config(data, "sim.toml (test)")


def commit(store: CalibrationStore, names: tuple[str, ...], when: datetime, valid_days: float, failure: str | None = None) -> None:
    """Parts ``names`` as calibrated at ``when`` and valid ``valid_days`` (each computed with the parts the set holds)."""
    for name in names:
        cur = store.current()
        inputs = {dep: cur.part(dep).id for dep in INPUTS[name]} if cur else {}  # type: ignore[union-attr]
        part = make_part(name, values=None if failure else VALUES[name], method="test", when=when, valid_days=valid_days,
                         inputs=inputs, failure=failure)  # fmt: skip
        store.commit(name, part, now=when)


def file_parts(root: Path) -> dict[str, Any]:
    """The parts of the set in use, as json reads them from the store's files."""
    return json.loads((root / (root / "current").read_text().strip()).read_text())["parts"]  # type: ignore[no-any-return]


def at(text: str) -> datetime:
    when = datetime.fromisoformat(text)
    assert when.utcoffset() == timedelta(0), text  # ISO 8601, UTC
    return when


async def calibration(client: httpx.AsyncClient) -> dict[str, Any]:
    r = await client.get("/calibration")
    assert r.status_code == 200, r.text
    return r.json()  # type: ignore[no-any-return]


async def test_lowering_max_age_days_expires_older_parts_at_once(tmp_path: Path) -> None:
    store = CalibrationStore(tmp_path / "calibration")
    commit(store, NAMES, datetime.now(timezone.utc) - timedelta(days=10), valid_days=90.0)
    parts = file_parts(store.root)
    assert {p["valid_days"] for p in parts.values()} == {90.0}
    async with running_service(tmp_path / "cell-5", cell_config(store.root, 5.0)) as service, api_client(service) as client:
        view = await calibration(client)
        assert (await client.get("/status")).json()["calibration"]["problems"] == view["problems"]
        for name in NAMES:  # 10 days old, a 5-day limit: expired 5 days ago, whatever the part recorded
            expires = at(parts[name]["calibrated_utc"]) + timedelta(days=5)
            assert any(p.startswith(f"{name}: expired on {expires:%Y-%m-%d %H:%M} UTC") for p in view["problems"]), (name, view["problems"])
            assert at(view["current"]["parts"][name]["expires_utc"]) == expires, name
        await to_execute(client)
        r = await client.post("/cycle", json={"recipe": "side-window", "part_id": "P-1"}, headers={**AUTH, "Idempotency-Key": "k1"})
        assert r.status_code == 409 and "cellctl teach" in r.json()["detail"], r.text  # its teaching is out of date
    async with running_service(tmp_path / "cell-90", cell_config(store.root, 90.0)) as service, api_client(service) as client:
        view = await calibration(client)
        for name in NAMES:
            assert at(view["current"]["parts"][name]["expires_utc"]) == at(parts[name]["calibrated_utc"]) + timedelta(days=90)
        assert view["problems"] == []


async def test_raising_max_age_days_applies_to_parts_calibrated_after(tmp_path: Path) -> None:
    store = CalibrationStore(tmp_path / "calibration")
    now = datetime.now(timezone.utc)
    commit(store, ("camera", "hand_eye"), now - timedelta(days=100), valid_days=90.0)  # calibrated under 90 days
    commit(store, ("laser", "teaching", "pixel_map"), now - timedelta(days=1), valid_days=180.0)  # under 180 days
    parts = file_parts(store.root)
    async with running_service(tmp_path / "cell", cell_config(store.root, 180.0)) as service, api_client(service) as client:
        view = await calibration(client)
        for name, days in (("camera", 90), ("hand_eye", 90), ("laser", 180), ("teaching", 180), ("pixel_map", 180)):
            assert at(view["current"]["parts"][name]["expires_utc"]) == at(parts[name]["calibrated_utc"]) + timedelta(days=days), name
        expired = sorted(p.split(":")[0] for p in view["problems"] if ": expired on " in p)
        assert expired == ["camera", "hand_eye"], view["problems"]


async def test_a_failed_part_has_no_expiry(tmp_path: Path) -> None:
    store = CalibrationStore(tmp_path / "calibration")
    now = datetime.now(timezone.utc)
    commit(store, ("camera", "hand_eye"), now, valid_days=90.0)
    commit(store, ("laser",), now, valid_days=90.0, failure="plane seen from too few directions")
    async with running_service(tmp_path / "cell", cell_config(store.root, 90.0)) as service, api_client(service) as client:
        parts = (await calibration(client))["current"]["parts"]
        assert parts["laser"]["status"] == "failed" and parts["laser"]["expires_utc"] is None
        assert at(parts["camera"]["expires_utc"]) == at(file_parts(store.root)["camera"]["calibrated_utc"]) + timedelta(days=90)
        assert parts["teaching"] is None
