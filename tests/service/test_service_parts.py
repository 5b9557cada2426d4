"""Part traceability over the real simulated cell: ``GET /parts``, ``GET /parts/{part_id}`` and ``cellctl parts``.

The cell runs on a versioned calibration set (the twin's truth committed as one, so that the
records carry a real version without half a minute of self-commissioning). Four windows are
installed into two car bodies over REST, the operator holding the last one mid-cycle. The records
are then checked against what the service reports elsewhere (the cycle records,
``GET /calibration``) and each image's recorded SHA-256 against the bytes the image route serves
(hashed here, independently). Files altered, deleted or pruned on disk show so. The export runs
as the real ``cellctl`` in a subprocess, against the same service on a loopback port.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import os
import sys
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from service_test_support import AUTH, TOKEN, api_client, running_service, served, to_execute

from cellctl.calibration.calibration_set import DEPENDS_ON, CalibrationStore, make_part
from cellctl.calibration.source import CalibrationSetSource
from cellctl.cell.cycle_values import CycleCalibration
from cellctl.domain import CycleStep
from cellctl.service.compose import Service

ROOT = Path(__file__).resolve().parents[2]
RECIPE = "side-window"
PLAN = (("G-A1", "CAR-A"), ("G-A2", "CAR-A"), ("G-B1", "CAR-B"))


def commit_as_set(directory: Path, cal: CycleCalibration) -> CalibrationStore:
    """A cycle calibration committed part by part as a versioned calibration set."""
    lens, t, m, taught = cal.lens, cal.template, cal.nine_point, cal.taught
    values = {
        "camera": {"K": lens.camera_matrix.tolist(), "dist": [lens.k1, lens.k2, lens.p1, lens.p2, lens.k3],
                   "image_size": [lens.width_px, lens.height_px]},
        "hand_eye": {"T_H_C": np.asarray(cal.T_H_C).tolist()},
        "laser": {"r": np.asarray(cal.laser_r).tolist(), "l": np.asarray(cal.laser_l).tolist()},
        "teaching": {"T0": taught.T0.tolist(), "C_Pos_0": taught.C_Pos_0.tolist(), "g_Pos_0": taught.g_Pos_0.tolist(),
                     "u_d": t.u_px, "v_d": t.v_px, "theta_d": t.theta_rad, "top_angle_d": t.top_angle_rad,
                     "right_angle_d": t.right_angle_rad},
        "pixel_map": {"affine": m.matrix.tolist(), "scale_mm_per_px": float(np.sqrt(abs(np.linalg.det(m.matrix[:, :2]))))},
    }  # fmt: skip
    quality = {"pixel_map": {"map_residuals_mm": m.residuals_mm.tolist(), "map_rms_mm": m.rms_mm, "map_max_mm": m.max_mm}}
    store, now = CalibrationStore(directory), datetime.now(timezone.utc)
    for name in ("camera", "hand_eye", "laser", "teaching", "pixel_map"):
        cur = store.current()
        inputs = {dep: cur.part(dep).id for dep in DEPENDS_ON[name]} if cur else {}  # type: ignore[union-attr]
        part = make_part(name, values=values[name], method="twin truth", when=now, valid_days=90.0, inputs=inputs, quality=quality.get(name))
        store.commit(name, part, now=now)
    return store


async def on_a_calibration_set(service: Service, directory: Path) -> None:
    """The cell switched from the oracle to a calibration set holding the oracle's calibration."""
    oracle = await asyncio.to_thread(service.orchestrator.calibration.cycle_calibration)
    store = commit_as_set(directory, oracle)
    service.orchestrator.calibration = CalibrationSetSource(store, service.config)


async def install(client: httpx.AsyncClient, part: str, car: str) -> dict[str, Any]:
    r = await client.post(
        "/cycle?wait=true&timeout_s=60", json={"recipe": RECIPE, "part_id": part, "car_id": car},
        headers={**AUTH, "Idempotency-Key": part},
    )  # fmt: skip
    assert r.status_code == 200 and r.json()["state"] == "done", r.text
    return r.json()


async def install_held_by_the_operator(service: Service, client: httpx.AsyncClient, part: str, car: str) -> int:
    """A cycle the operator holds (POST /commands/hold) as soon as it starts to align."""
    events = service.orchestrator.events.subscribe()
    try:
        r = await client.post("/cycle", json={"recipe": RECIPE, "part_id": part, "car_id": car}, headers={**AUTH, "Idempotency-Key": part})
        assert r.status_code == 202, r.text
        cid = r.json()["cycle_id"]
        while (ev := await asyncio.wait_for(events.get(), 30)).kind != "step" or ev.data != {"cycle_id": cid, "step": "align"}:
            pass
        assert (await client.post("/commands/hold", headers=AUTH)).status_code == 200
    finally:
        service.orchestrator.events.unsubscribe(events)
    record = await service.orchestrator.wait_cycle(cid, 30)
    assert record.state.value == "failed" and record.error and record.error.startswith("stopped"), record
    return cid


async def cellctl(url: str, *args: str) -> tuple[int, str, str]:
    """``cellctl`` (``python -m cellctl.cli``) in a subprocess, the operator's token in its environment."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "cellctl.cli", "--config", str(ROOT / "config" / "sim.toml"), *args[:2], "--url", url, *args[2:],
        stdin=asyncio.subprocess.DEVNULL, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        env={**os.environ, "CELLCTL_TOKEN": TOKEN},
    )  # fmt: skip
    out, err = await asyncio.wait_for(proc.communicate(), 60)
    return int(proc.returncode or 0), out.decode(), err.decode()


async def test_every_install_of_a_car_body_is_traced_and_exported(tmp_path: Path) -> None:
    async with running_service(tmp_path) as service, api_client(service) as client:
        await on_a_calibration_set(service, tmp_path / "calibration")
        await to_execute(client)
        start = datetime.now(timezone.utc)
        records = {part: await install(client, part, car) for part, car in PLAN}
        held = await install_held_by_the_operator(service, client, "G-B2", "CAR-B")
        calibration = (await client.get("/calibration")).json()["current"]["version"]
        assert calibration is not None

        # A car body's installs, exactly, each complete and consistent with the rest of the API.
        page = (await client.get("/parts", params={"car_id": "CAR-A"})).json()
        assert [i["cycle_id"] for i in page["installs"]] == [records["G-A1"]["id"], records["G-A2"]["id"]]
        assert page["next"] is None
        for item in page["installs"]:
            cycle = (await client.get(f"/cycles/{item['cycle_id']}")).json()
            assert (item["recipe"], item["car_id"], item["part_id"], item["state"]) == (RECIPE, "CAR-A", cycle["part_id"], "done")
            assert item["calibration_version"] == str(calibration)
            assert item["measured_deviation"] == cycle["measured_deviation"] and item["measured_deviation"] is not None
            assert item["ok"] is cycle["part_ok"] and item["error_code"] == (0 if item["ok"] else item["error_code"])
            assert item["correction_mm"] == cycle["result"]["correction_mm"] and item["cycle_time_s"] > 0
            assert [s["step"] for s in item["steps"]] == [s["step"] for s in cycle["steps"]]
            for step, seen in zip(item["steps"], cycle["steps"], strict=True):
                assert step["figures"] == seen["figures"] and step["ok"] is True and step["duration_s"] is not None
            # Every step has its figures (a shot's record is its image); the images name the steps that took them.
            figured = {s["step"] for s in item["steps"] if s["figures"]}
            assert {s["step"] for s in item["steps"]} - figured <= {"shoot"}, figured
            assert item["images"] and {i["step"] for i in item["images"]} <= {s["step"] for s in item["steps"]}
            for image in item["images"]:
                served_png = await client.get(image["url"])
                assert served_png.status_code == 200
                assert image["sha256"] == hashlib.sha256(served_png.content).hexdigest()
                assert image["size_bytes"] == len(served_png.content) and image["status"] == "ok"

        # The operator's hold is among the held install's actions, with who gave it and from where.
        (held_item,) = (await client.get("/parts/G-B2")).json()["installs"]
        assert held_item["cycle_id"] == held and held_item["ok"] is False and held_item["reason"].startswith("stopped")
        hold = [a for a in held_item["actions"] if a["action"] == "command:hold"]
        assert len(hold) == 1 and hold[0]["actor"] == "operator" and hold[0]["source"].startswith("rest:")
        assert (await client.get("/parts", params={"car_id": "CAR-B"})).json()["installs"][-1] == held_item

        # The image files now: altered, deleted, pruned by retention, and one recorded without a digest.
        a1, a2 = (await client.get("/parts/G-A1")).json()["installs"][0], (await client.get("/parts/G-A2")).json()["installs"][0]
        image_dir = service.orchestrator.image_dir
        altered = image_dir / a1["images"][0]["uri"]
        altered.write_bytes(altered.read_bytes()[:-1] + b"\0")  # same size, one byte changed
        (image_dir / a1["images"][1]["uri"]).unlink()
        await service.store.mark_images_pruned([a2["images"][0]["uri"]], reason="test: retention", at=start)
        await service.store.add_image(a2["cycle_id"], CycleStep.INSPECT, name="legacy", uri=a2["images"][1]["uri"])
        statuses = {i["name"]: i["status"] for i in (await client.get("/parts/G-A1")).json()["installs"][0]["images"]}
        assert [statuses[a1["images"][k]["name"]] for k in (0, 1)] == ["altered", "missing"], statuses
        a2_images = (await client.get("/parts/G-A2")).json()["installs"][0]["images"]
        assert a2_images[0]["status"] == "pruned" and a2_images[0]["pruned_reason"] == "test: retention"
        assert a2_images[-1]["name"] == "legacy" and a2_images[-1]["status"] == "unrecorded" and a2_images[-1]["sha256"] is None

        # Paging by cursor gives every install once; a time window lists the installs that ended in it.
        seen, after = [], None
        while True:
            page = (await client.get("/parts", params={"limit": 1, **({"after": after} if after else {})})).json()
            seen += [i["cycle_id"] for i in page["installs"]]
            if (after := page["next"]) is None:
                break
        everything = [records[p]["id"] for p, _ in PLAN] + [held]
        assert seen == everything
        window = {"since": start.isoformat(), "until": (datetime.now(timezone.utc) + timedelta(seconds=1)).isoformat()}
        in_window = (await client.get("/parts", params=window)).json()["installs"]
        assert [i["cycle_id"] for i in in_window] == everything
        assert (await client.get("/parts", params={"until": start.isoformat()})).json()["installs"] == []

        # The MES export: the same documents as JSON lines, written atomically; a bad --since is one clear line.
        async with served(service) as url:
            out = tmp_path / "export" / "parts.jsonl"
            out.parent.mkdir()
            code, stdout, stderr = await cellctl(url, "parts", "export", "--since", window["since"], "--until", window["until"],
                                                 "--output", str(out))  # fmt: skip
            assert code == 0, stderr
            lines = out.read_text(encoding="utf-8").splitlines()
            assert [json.loads(line) for line in lines] == in_window and stdout == ""
            assert "wrote 4 part installs" in stderr and sorted(p.name for p in out.parent.iterdir()) == ["parts.jsonl"]
            code, stdout, _ = await cellctl(url, "parts", "export", "--since", window["since"], "--car-id", "CAR-B")
            assert code == 0 and [json.loads(line)["cycle_id"] for line in stdout.splitlines()] == [records["G-B1"]["id"], held]
            code, stdout, stderr = await cellctl(url, "parts", "export", "--since", "2026-03-01 06:00", "--output", str(out))
            assert code == 2 and stdout == "" and len(stderr.strip().splitlines()) == 1, stderr
            assert "--since" in stderr and "no timezone" in stderr and "ISO 8601" in stderr
            assert out.read_text(encoding="utf-8").splitlines() == lines  # the refused export left the file alone
            code, stdout, stderr = await cellctl(url, "parts", "show", "G-A1")
            assert code == 0, stderr
            assert f"cycle {a1['cycle_id']}: done" in stdout and "altered" in stdout and "missing" in stdout
            code, _, stderr = await cellctl(url, "parts", "show", "G-none")
            assert code == 1 and "404" in stderr and "G-none" in stderr


async def test_bad_part_queries_are_refused_naming_the_field(tmp_path: Path) -> None:
    async with running_service(tmp_path) as service, api_client(service) as client:
        cases = [
            ({"since": "2026-03-01T06:00:00"}, ["since", "no timezone", "ISO 8601"]),
            ({"until": "yesterday"}, ["until"]),
            ({"since": "2026-03-01T06:00:00Z", "until": "2026-03-01T05:00:00Z"}, ["until", "later than since"]),
            ({"since": "0001-01-01T00:00:00+05:00"}, ["since", "out of range"]),
            ({"limit": "0"}, ["limit"]),
            ({"limit": "201"}, ["limit"]),
            ({"after": "-1"}, ["after"]),
            ({"car_id": ""}, ["car_id"]),
            ({"part_id": "x" * 129}, ["part_id"]),
        ]
        for params, names in cases:
            r = await client.get("/parts", params=params)
            assert r.status_code == 422, (params, r.text)
            for name in names:
                assert name in r.json()["detail"], (params, r.json())
        r = await client.get("/parts/G-none")
        assert r.status_code == 404 and "G-none" in r.json()["detail"]
        assert (await client.get("/parts", params={"since": "2026-03-01T06:00:00+01:00"})).json() == {"installs": [], "next": None, "until": None}
        schema = (await client.get("/openapi.json")).json()
        assert schema["paths"]["/parts"]["get"]["responses"]["200"]["content"]["application/json"]["schema"] == {
            "$ref": "#/components/schemas/PartsPage"
        }
        assert {"PartInstall", "PartImage", "PartAction", "PartHistory"} <= set(schema["components"]["schemas"])
