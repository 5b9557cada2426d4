"""Reading the wall on the move (issue 19), through the whole simulated service, scored against the twin's truth.

The twin's own devices can store laser readings and stream the robot's pose; its sensor answers
late by ``sim.laser.storage_latency_s`` and its feedback is stamped late by
``sim.robot.feedback_latency_s``, and the true flange trails the reported path by
``sim.robot.path_lag_s``. The cell knows none of them: it times the laser against the robot from
the approach of a sweep, keeps it, and checks it on each later sweep.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from service_test_support import AUTH, api_client, running_service, sim_config, to_execute

from cellctl.domain import AlarmCode
from cellctl.sim.devices import FeedbackFault

AXES_MM = ("dx_mm", "dy_mm", "dz_mm")
AXES_DEG = ("drx_deg", "dry_deg", "drz_deg")
TWIN_DEVICES = {"laser": {"kind": "sim"}, "robot": {"kind": "sim"}}


async def _cycles(tmp_path: Path, mode: str, n: int, devices: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    config = sim_config(**{"process.align": {"mode": mode}, "devices": devices or TWIN_DEVICES, "sim": {"seed": 7}, "plc": {"port": 0}})
    out = []
    async with running_service(tmp_path / mode, config) as service, api_client(service) as client:
        await to_execute(client)
        for i in range(n):
            r = await client.post(
                "/cycle?wait=true&timeout_s=120", json={"recipe": "side-window", "part_id": f"{mode}-{i}"},
                headers={**AUTH, "Idempotency-Key": f"{mode}-{i}"},
            )  # fmt: skip
            assert r.status_code in (200, 201), r.text
            rec = r.json()
            detail = await client.get(f"/cycles/{rec['id']}")
            out.append(detail.json())
        twin = service.orchestrator.truth.cell.config
        # the sensor's delay, plus the servo lag of the true flange behind the reported path, minus the feedback's
        latency_ms = 1e3 * (twin.laser.storage_latency_s + twin.robot.path_lag_s - twin.robot.feedback_latency_s)
    for rec in out:
        rec["twin_latency_ms"] = latency_ms
    return out


def _align(rec: dict[str, Any]) -> dict[str, Any]:
    return next(s["figures"] for s in rec["steps"] if s["step"] == "align")


async def test_on_the_move_installs_as_well_as_stop_and_go_in_less_robot_time(tmp_path: Path) -> None:
    fly = await _cycles(tmp_path, "on_the_fly", 3)
    stop = await _cycles(tmp_path, "stop_and_go", 1)
    for rec in fly:
        assert rec["state"] == "done", rec.get("error")
        a = _align(rec)
        assert a["mode"] == "on_the_fly" and a["readings_fitted"] >= 100, a
        # the latency the cell estimated is the one the twin was given, within 1 ms (the bar)
        assert abs(a["latency_ms"] - rec["twin_latency_ms"]) < 1.0, (a["latency_ms"], rec["twin_latency_ms"])
        te = rec["true_error"]
        assert all(abs(te[k]) < 0.3 for k in AXES_MM) and all(abs(te[k]) < 0.05 for k in AXES_DEG), te
        assert rec["result"]["step_time_s"]["align"] < stop[0]["result"]["step_time_s"]["align"]
        # the flush measured on the move too: the cell's own measurement agrees with the truth
        inspect = next(s["figures"] for s in rec["steps"] if s["step"] == "inspect")
        crossings = inspect["flush_sweep"]["crossings"]  # one leg's readings either side of an edge, near and far on both
        assert len(crossings) == 4 and all(min(c["glass_readings"], c["wall_readings"]) >= 10 for c in crossings), inspect
        off = {k: rec["measured_deviation"][k] - te[k] for k in AXES_MM + AXES_DEG}
        assert all(abs(off[k]) < 0.06 for k in AXES_MM) and all(abs(off[k]) < 0.02 for k in AXES_DEG), off
        assert abs(off["dz_mm"]) < 0.02, off  # stop and go: 10 pairs of stops, each with the robot's repeatability
    assert fly[0]["result"]["cycle_time_s"] < stop[0]["result"]["cycle_time_s"]
    assert _align(stop[0])["mode"] == "stop_and_go"


async def test_on_the_move_falls_back_to_reading_standing_where_it_was_taught_when_the_robot_streams_no_pose(
    tmp_path: Path,
) -> None:
    # the ABB driver over its fake without EGM: no position feedback stream, so the wall is read standing, at the
    # points along the sweep's path that the cell's own teaching read (it commissioned itself, on the move)
    rec = (await _cycles(tmp_path, "on_the_fly", 1, devices={"laser": {"kind": "sim"}, "robot": {"kind": "sim_abb", "egm": False}}))[0]
    assert rec["state"] == "done", rec.get("error")
    a = _align(rec)
    assert a["mode"] == "stop_and_go" and "position feedback" in a["on_the_fly_unavailable"], a
    align = sim_config(**{"process.align": {"mode": "on_the_fly"}}).process.align
    assert a["spots_along"] == "process.align.sweep.path_mm" and len(a["spots"]) == len(align.wall_spots_mm()) > 6, a
    assert a["stops"] == list(align.wall_stops()) and a["spots_without_reading"] == [], a
    te = rec["true_error"]
    assert all(abs(te[k]) < 0.3 for k in AXES_MM) and all(abs(te[k]) < 0.05 for k in AXES_DEG), te


async def _one_cycle_with_fault(
    tmp_path: Path, fault: FeedbackFault, *, time_scale: float = 0.001
) -> tuple[dict[str, Any], Any, dict[str, Any]]:
    sim = {"seed": 7, "time_scale": time_scale}
    config = sim_config(**{"process.align": {"mode": "on_the_fly"}, "devices": TWIN_DEVICES, "sim": sim, "plc": {"port": 0}})
    async with running_service(tmp_path, config) as service, api_client(service) as client:
        await to_execute(client)
        rig = service.orchestrator.truth
        rig.robot.feedback_fault = fault
        rig.stops = []  # whether the arm was moving at each stop request
        inner_stop = rig.robot.stop

        async def stop(*, timeout_s: float) -> None:
            rig.stops.append(rig.cell.arm.moving())
            await inner_stop(timeout_s=timeout_s)

        rig.robot.stop = stop
        r = await client.post(
            "/cycle?wait=true&timeout_s=120", json={"recipe": "side-window", "part_id": "fault"},
            headers={**AUTH, "Idempotency-Key": "fault"},
        )  # fmt: skip
        assert r.status_code in (200, 201), r.text
        rec = (await client.get(f"/cycles/{r.json()['id']}")).json()
        status = (await client.get("/status")).json()
        return rec, rig, status


async def test_a_few_lost_feedback_samples_do_not_stop_the_cycle(tmp_path: Path) -> None:
    rec, rig, _status = await _one_cycle_with_fault(tmp_path, FeedbackFault(drop_fraction=0.05))
    assert rec["state"] == "done", rec.get("error")
    assert rig.stops == []
    a = _align(rec)
    assert a["mode"] == "on_the_fly" and a["paired_readings"] >= 0.9 * a["readings_with_distance"], a


async def test_feedback_stopping_mid_path_stops_the_robot_with_an_alarm_and_fits_no_plane(tmp_path: Path) -> None:
    # 5 % of the samples lost, then none at all 3 s into the stream: on the first leg of the path.
    # A simulated second lasts 0.1 s here, so that leg (2.2 s) lasts 220 ms of real time and the
    # supervision's 2 ms polls find the robot on it even on a loaded machine. At the suite's usual
    # thousandth the leg takes 2 ms, and a late poll could land after it (CI failed so once).
    fault = FeedbackFault(drop_fraction=0.05, stop_after_s=3.0)
    rec, rig, status = await _one_cycle_with_fault(tmp_path, fault, time_scale=0.1)
    assert rec["state"] == "failed" and rec["result"]["error_code"] == int(AlarmCode.POSITION_FEEDBACK_LOST), rec
    assert "position feedback stopped mid-path" in rec["error"] and "robot was stopped" in rec["error"]
    align = next(s for s in rec["steps"] if s["step"] == "align")
    assert align["ok"] is False and "normal_B" not in align["figures"]  # no plane was fitted to guesses
    assert not any(s["step"] == "install" for s in rec["steps"])  # nothing installed on a wrong plane
    assert rig.stops[:1] == [True]  # stopped in the middle of a leg, not after it
    assert not rig.cell.arm.moving() and rig.cell.glass_on_gripper  # the robot stands, the glass is still held
    assert status["stop_reason"]["code"] == int(AlarmCode.POSITION_FEEDBACK_LOST)


async def test_a_latency_known_from_commissioning_skips_the_timing_moves(tmp_path: Path) -> None:
    config = sim_config(**{"process.align": {"mode": "on_the_fly"}, "process.align.sweep": {"fixed_latency_s": 0.0073},
                           "devices": TWIN_DEVICES, "sim": {"seed": 7}, "plc": {"port": 0}})  # fmt: skip
    async with running_service(tmp_path, config) as service, api_client(service) as client:
        await to_execute(client)
        moves: list[np.ndarray] = []
        robot = service.orchestrator.truth.robot
        inner_move = robot.move

        async def move(request: Any, *, timeout_s: float) -> Any:
            moves.append(np.array(request.target.position_mm))
            return await inner_move(request, timeout_s=timeout_s)

        robot.move = move
        r = await client.post("/cycle?wait=true&timeout_s=120", json={"recipe": "side-window", "part_id": "k"},
                              headers={**AUTH, "Idempotency-Key": "k"})  # fmt: skip
        rec = (await client.get(f"/cycles/{r.json()['id']}")).json()
    assert rec["state"] == "done", rec.get("error")
    a = _align(rec)
    assert a["latency_ms"] == 7.3 and "latency_sigma_ms" not in a  # taken as given, not estimated
    # the first move goes to the path's first corner and the second along the first leg (1560 mm), where
    # estimating the latency would first move 40 mm in, out and in along the beam
    assert np.linalg.norm(moves[1] - moves[0]) > 1000.0, moves[:3]


async def test_the_kept_latency_is_checked_each_cycle_and_a_changed_one_is_caught_and_timed_anew(tmp_path: Path) -> None:
    config = sim_config(**{"process.align": {"mode": "on_the_fly"}, "devices": TWIN_DEVICES, "sim": {"seed": 7},
                           "plc": {"port": 0}})  # fmt: skip
    recs: list[dict[str, Any]] = []
    beam_moves: list[int] = []
    async with running_service(tmp_path, config) as service, api_client(service) as client:
        await to_execute(client)
        rig = service.orchestrator.truth
        moves: list[np.ndarray] = []
        inner_move = rig.robot.move

        async def move(request: Any, *, timeout_s: float) -> Any:
            moves.append(np.array(request.target.position_mm))
            return await inner_move(request, timeout_s=timeout_s)

        rig.robot.move = move
        for i in range(4):
            if i == 2:  # the sensor's response changes (another averaging set on the controller): 4.7 ms later
                laser = rig.cell.config.laser.model_copy(update={"storage_latency_s": 0.0127})
                rig.cell.config = rig.cell.config.model_copy(update={"laser": laser})
            moves.clear()
            r = await client.post("/cycle?wait=true&timeout_s=120", json={"recipe": "side-window", "part_id": f"k{i}"},
                                  headers={**AUTH, "Idempotency-Key": f"k{i}"})  # fmt: skip
            recs.append((await client.get(f"/cycles/{r.json()['id']}")).json())
            # the 40 mm moves along the beam at the path's first corner, from the start (40 mm out) on
            steps = [float(np.linalg.norm(b - a)) for a, b in zip(moves, moves[1:])]
            beam_moves.append(next(k for k, s in enumerate(steps) if abs(s - 40.0) > 0.5))
        twin = rig.cell.config
        new_ms = 1e3 * (twin.laser.storage_latency_s + twin.robot.path_lag_s - twin.robot.feedback_latency_s)
    aligns = [_align(rec) for rec in recs]
    assert [rec["state"] for rec in recs] == ["done"] * 4, [rec.get("error") for rec in recs]
    assert [a["latency"] for a in aligns] == ["timed", "checked", "checked", "timed"]
    assert beam_moves == [3, 1, 1, 3]  # in, out and in to time; in once to check
    assert aligns[1]["latency_check"]["agrees"] and aligns[1]["latency_ms"] == aligns[0]["latency_ms"]
    check = aligns[2]["latency_check"]
    assert not check["agrees"] and abs(check["off_ms"] - 4.7) < 1.0, check  # caught on the move in
    assert abs(aligns[2]["latency_ms"] - new_ms) < 1.0  # that cycle already pairs with what the check found
    assert "the last check found" in aligns[3]["timed_because"] and abs(aligns[3]["latency_ms"] - new_ms) < 1.0
    for rec in recs:
        te = rec["true_error"]
        assert all(abs(te[k]) < 0.3 for k in AXES_MM) and all(abs(te[k]) < 0.05 for k in AXES_DEG), te


async def test_the_walls_distance_comes_from_the_sweeps_stops_not_from_the_arm_deflected_at_speed(tmp_path: Path) -> None:
    # A robot that deflects 0.3 mm sideways at 1000 mm/s (three times the twin's default): the readings on
    # the legs lie off the reported path; those taken where the sweep stands do not. The flush on the move
    # reads glass and wall on one leg across an edge, so the deflection, the same for both, leaves it alone.
    config = sim_config(**{"process.align": {"mode": "on_the_fly"}, "devices": TWIN_DEVICES, "plc": {"port": 0},
                           "sim": {"seed": 7, "robot": {"path_sideways_s": 0.0003}}})  # fmt: skip
    async with running_service(tmp_path, config) as service, api_client(service) as client:
        await to_execute(client)
        r = await client.post("/cycle?wait=true&timeout_s=120", json={"recipe": "side-window", "part_id": "d"},
                              headers={**AUTH, "Idempotency-Key": "d"})  # fmt: skip
        rec = (await client.get(f"/cycles/{r.json()['id']}")).json()
    assert rec["state"] == "done", rec.get("error")
    a = _align(rec)
    assert a["readings_at_rest"] >= 30 and abs(a["rest_shift_mm"]) > 0.15, a  # the cell saw the deflection
    corners = a["readings_at_rest_per_corner"]  # read standing at every corner of the path, each weighing the same
    assert len(corners) == len(config.process.align.sweep.path_mm) and min(corners) >= 3 and sum(corners) == a["readings_at_rest"], a
    assert abs(rec["true_error"]["dz_mm"]) < 0.12, rec["true_error"]  # and it did not reach the install
    off = {k: rec["measured_deviation"][k] - rec["true_error"][k] for k in ("dz_mm", "drx_deg", "dry_deg")}
    assert abs(off["dz_mm"]) < 0.02 and abs(off["drx_deg"]) < 0.005 and abs(off["dry_deg"]) < 0.005, off


async def test_a_move_in_too_short_to_check_the_latency_is_refused_naming_what_gives_more_readings(tmp_path: Path) -> None:
    # 10 mm in along the beam at 1000 mm/s and its settle last 0.29 s: 14 readings at a 20 ms storage cycle, fewer
    # than the timing needs. The first cycle moves in, out and in (about 40 readings) and times the laser; the second
    # checks the kept latency on one move in and is refused, saying how many it needs and what gives more.
    sweep = {"approach_mm": 10.0, "storage_cycle_s": 0.02}
    config = sim_config(**{"process.align": {"mode": "on_the_fly"}, "process.align.sweep": sweep,
                           "devices": TWIN_DEVICES, "sim": {"seed": 7}})  # fmt: skip
    async with running_service(tmp_path, config) as service, api_client(service) as client:
        await to_execute(client)
        states = []
        for i in range(2):
            r = await client.post(
                "/cycle?wait=true&timeout_s=120", json={"recipe": "side-window", "part_id": f"short-{i}"},
                headers={**AUTH, "Idempotency-Key": f"short-{i}"},
            )  # fmt: skip
            states.append(r.json())
            if i == 0:
                assert states[0]["state"] == "done", states[0].get("error")
    error = states[1]["error"] or ""
    assert states[1]["state"] == "failed" and "laser readings (at least 20 needed)" in error, error
    assert "process.align.sweep.approach_mm" in error, error
