"""A damaged calibration set file (issue 15 item 6): read when it changes, refused once with its own
alarm, the status routes keep answering 200, and a cycle fails with the calibration alarm (1305)."""

from __future__ import annotations

import asyncio
import json
import logging
from datetime import datetime, timezone
from pathlib import Path

import pytest
from calib_test_support import INPUTS, VALUES
from service_test_support import AUTH, api_client, running_service, sim_config, to_execute

from cellctl.calibration.calibration_set import CalibrationStore, make_part
from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.source import CalibrationSetSource
from cellctl.cell.alarms import AlarmCode
from cellctl.config import load_config

ROOT = Path(__file__).resolve().parents[2]


def write_valid_set(root: Path) -> CalibrationStore:
    """Five versions, the last one complete and in date."""
    store = CalibrationStore(root)
    now = datetime.now(timezone.utc)
    for name in ("camera", "hand_eye", "laser", "teaching", "pixel_map"):
        cur = store.current()
        inputs = {dep: cur.part(dep).id for dep in INPUTS[name]} if cur else {}  # type: ignore[union-attr]
        store.commit(name, make_part(name, values=VALUES[name], method="test", when=now, valid_days=90.0, inputs=inputs), now=now)
    return store


def bad_field(text: str) -> str:
    """The same set with fx negative: valid JSON, one bad field."""
    data = json.loads(text)
    data["parts"]["camera"]["values"]["K"][0][0] = -5249.6
    return json.dumps(data, indent=2)


def cellctl_records(caplog: pytest.LogCaptureFixture) -> list[logging.LogRecord]:
    return [r for r in caplog.records if r.name.startswith("cellctl") and r.levelno >= logging.WARNING]


def test_the_source_reads_the_set_only_when_it_changes_and_refuses_a_damaged_one(tmp_path: Path) -> None:
    store = write_valid_set(tmp_path / "cal")
    source = CalibrationSetSource(store, load_config(ROOT / "config" / "sim.toml"))
    assert source.problems() == [] and source.reads == 1
    for _ in range(50):
        source.problems(), source.summary(), source.reference()
    assert source.reads == 1  # four /status calls a second cost two stat calls each, no parsing
    first = source.cycle_calibration()
    assert source.cycle_calibration() is first

    current = tmp_path / "cal" / "set-000005.json"
    good = current.read_text()
    current.write_text(good[: len(good) // 2])  # truncated: not JSON
    problems = source.problems()
    assert len(problems) == 1 and "set-000005.json: not valid JSON" in problems[0]
    assert "set-000004.json" in problems[0]  # the way out: an earlier version
    for _ in range(20):
        assert source.problems() == problems
    assert source.reads == 2
    with pytest.raises(CalibrationRefused, match="damaged") as refused:
        source.cycle_calibration()
    assert refused.value.reason == "damaged"
    assert source.summary()["damaged"] == problems[0] and source.summary()["version"] == 5
    history = source.history()
    assert [r["version"] for r in history] == [1, 2, 3, 4, 5] and "not valid JSON" in history[-1]["damaged"]
    assert history[3]["parts"]["laser"] == "ok"

    current.write_text(bad_field(good))
    (problem,) = source.problems()
    assert "parts.camera.values.K" in problem and "fx, fy > 0" in problem

    current.write_text(good)  # repaired
    assert source.problems() == [] and source.cycle_calibration() is not first  # rebuilt from the file read again


@pytest.mark.timeout(120)
async def test_a_damaged_set_file_keeps_the_status_up_raises_one_alarm_and_refuses_cycles_with_1305(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    cal_dir = tmp_path / "cal"
    write_valid_set(cal_dir)
    config = sim_config(
        calibration={"source": "set", "auto_calibrate_in_sim": False, "directory": str(cal_dir)}, plc={"enabled": False}
    )
    async with running_service(tmp_path / "work", config) as service, api_client(service) as client:
        source = service.orchestrator.calibration
        assert isinstance(source, CalibrationSetSource)
        r = await client.get("/status")
        assert r.status_code == 200 and r.json()["calibration"]["problems"] == []
        reads = source.reads

        current = cal_dir / "set-000005.json"
        good = current.read_text()
        current.write_text("{ this is not json")
        caplog.clear()
        with caplog.at_level(logging.DEBUG, logger="cellctl"):
            for _ in range(40):  # ten seconds of a dashboard at four calls a second
                r = await client.get("/status")
                assert r.status_code == 200, r.text
            for route in ("/calibration", "/health", "/metrics", "/alarms"):
                assert (await client.get(route)).status_code == 200, route
            await asyncio.sleep(0.05)  # the alarm is raised on the loop
        problems = r.json()["calibration"]["problems"]
        assert len(problems) == 1 and "set-000005.json: not valid JSON" in problems[0]
        assert (await client.get("/calibration")).json()["current"]["damaged"] == problems[0]
        assert source.reads == reads + 1  # read once when it changed, not per request
        # One warning, no traceback anywhere.
        warned = cellctl_records(caplog)
        assert [r.getMessage().split(":")[0] for r in warned] == ["calibration set refused"]
        assert not any(r.exc_info for r in caplog.records)
        alarms = [a for a in service.orchestrator.alarms.current() if a.code == AlarmCode.CALIBRATION_INVALID]
        assert len(alarms) == 1 and alarms[0].source == "calibration" and "set-000005.json" in alarms[0].message

        # A cycle then fails with the calibration alarm's code, not as a software fault.
        assert (await client.post("/alarms/acknowledge-all", headers=AUTH)).status_code == 200
        await to_execute(client)
        caplog.clear()
        with caplog.at_level(logging.DEBUG, logger="cellctl"):
            r = await client.post(
                "/cycle?wait=true&timeout_s=60", json={"recipe": "side-window", "part_id": "P-1"},
                headers={**AUTH, "Idempotency-Key": "damaged-1"},
            )  # fmt: skip
        assert r.status_code == 200, r.text
        cycle = r.json()
        assert cycle["state"] == "failed" and cycle["result"]["error_code"] == int(AlarmCode.CALIBRATION_INVALID)
        assert "not valid JSON" in cycle["error"]
        assert not any(r.exc_info for r in caplog.records)
        codes = {int(a.code) for a in service.orchestrator.alarms.current()}
        assert int(AlarmCode.TASK_FAILED) not in codes and int(AlarmCode.CALIBRATION_INVALID) in codes

        # A bad field: refused again (a new change of the file), naming the field.
        current.write_text(bad_field(good))
        r = await client.get("/status")
        assert r.status_code == 200 and "parts.camera.values.K" in r.json()["calibration"]["problems"][0]

        # Repaired: production may go on.
        current.write_text(good)
        assert (await client.get("/status")).json()["calibration"]["problems"] == []
