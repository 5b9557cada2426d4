"""``cellctl bench cycle-time``: both modes on one cell, and where their robot time goes, against the configured path."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cellctl.bench.cycle_time import COMPUTING, format_cycle_time, run_cycle_time, sweep_legs_s
from cellctl.config import load_config

ROOT = Path(__file__).resolve().parents[2]


def _length_mm(corners: tuple[tuple[float, float], ...]) -> float:
    return float(np.sum(np.linalg.norm(np.diff(np.asarray(corners, dtype=float), axis=0), axis=1)))


def test_each_mode_says_where_its_robot_time_goes_and_the_sweeps_take_at_least_their_paths() -> None:
    config = load_config(ROOT / "config" / "sim.toml")
    out = run_cycle_time(config, cells=1, trials=1, seed=2, progress=False)
    slow, fast = out["stop_and_go"], out["on_the_fly"]
    assert slow["installed"] == fast["installed"] == 1 and fast["aligned_on_the_fly"] == 1
    align, inspect, twin = config.process.align, config.process.inspect, config.sim
    # Each sweep at most at the travel speed for what the gripper holds: the alignment's carries the glass.
    held_v, empty_v = (config.process.sweep_speed_mm_s(glass_on_gripper=g) for g in (True, False))
    motion = config.process.motion
    assert held_v == motion.travel_speed_mm_s < empty_v == motion.empty_travel_speed_mm_s < align.sweep.speed_mm_s
    swept = (f"moves at {held_v:g} mm/s", f"moves at {empty_v:g} mm/s")
    at_sweep_speeds = sum(fast["spent_median_s"].get(n, 0.0) for n in swept)
    for mode in (slow, fast):
        spent = mode["spent_median_s"]
        assert spent[COMPUTING] >= 0.0  # every wait the ledger holds fell within the cycle
        assert sum(spent.values()) == pytest.approx(mode["cycle_median_s"])
        assert spent["gripper"] == pytest.approx(twin.robot.gripper_settle_s)  # the glass comes held; let go once
    # On the move the laser spot runs the alignment's path (after the moves along the beam that time the
    # laser) and the inspection's at their speeds: at least their lengths at those speeds, ramps, settling and
    # the travels to and from them on top. Stop and go reads nothing out.
    swept_s = (_length_mm(align.sweep.path_mm) + 3 * align.sweep.approach_mm) / held_v + _length_mm(inspect.sweep_path_mm) / empty_v
    assert swept_s < at_sweep_speeds < 2.0 * swept_s
    assert "laser read-out" not in slow["spent_median_s"]
    # The storage, read out over the serial line: a reading every storage cycle along the sweeps.
    readings = swept_s / align.sweep.storage_cycle_s
    assert fast["spent_median_s"]["laser read-out"] > readings * twin.laser.readout_s_per_reading
    # The install's and the inspection's moves are the same in both modes.
    # (The glass's turns at 30 deg/s, mostly the install's, also lead an alignment's last move where it is short.)
    shared = [f"turns at {motion.empty_speed_deg_s:g} deg/s", f"moves at {motion.fine_speed_mm_s:g} mm/s"]
    assert all(slow["spent_median_s"][n] == pytest.approx(fast["spent_median_s"][n], abs=0.05) for n in shared)
    glass_turns = f"turns at {motion.speed_deg_s:g} deg/s"
    assert fast["spent_median_s"][glass_turns] == pytest.approx(slow["spent_median_s"][glass_turns], abs=1.0)
    text = format_cycle_time(out)
    assert "where the time goes" in text and "RMS e stop and go / on the move" in text
    # The sweeps' legs with their stops are part of the moves at the sweep speed (which add the moves that time the laser).
    legs = out["sweep_legs"]
    assert legs["flown_s"] < legs["stopping_s"] < at_sweep_speeds and legs["speeds_mm_s"] == [held_v, empty_v]
    assert f"take {legs['stopping_s']:.2f} s stopping at every corner" in text
    # the one cycle timed the laser (the first sweep of a service does): within 1 ms of the twin's latency
    assert fast["latency_estimates"] == 1 and out["latency_error_ms_max"] < 1.0
    assert f"of the twin's {out['true_latency_ms']:.2f} ms (bar 1 ms)" in text
    for mode in (slow, fast):  # one cycle a mode: its error is its own mean, RMS and p99
        assert all(mode["rms"][k] == pytest.approx(abs(mode["mean"][k])) == pytest.approx(mode["p99_abs"][k]) for k in mode["rms"])


def test_the_sweeps_legs_take_the_trapezoids_closed_form_stopping_or_flown_through() -> None:
    """Each leg from rest to rest: L/v + v/a above v^2/a, 2 sqrt(L/a) below, and the settle; flown through,
    one such move over each sweep's length, but for the alignment's, which turns back up the side: two there."""
    config = load_config(ROOT / "config" / "sim.toml")
    sweep, robot = config.process.align.sweep, config.sim.robot
    a, settle = robot.acceleration_mm_s2, robot.settle_time_s
    v = config.process.motion.travel_speed_mm_s  # the alignment's sweep carries the glass

    def rest_to_rest(L: float) -> float:
        return (L / v + v / a if L >= v * v / a else 2.0 * np.sqrt(L / a)) + settle

    def legs(corners: tuple[tuple[float, float], ...]) -> list[float]:
        p = np.asarray(corners, dtype=float)
        return [float(np.hypot(*(q - r))) for r, q in zip(p[:-1], p[1:])]

    align, inspect = [sweep.approach_mm, *legs(sweep.path_mm)], legs(config.process.inspect.sweep_path_mm)
    got = sweep_legs_s(config)
    align_stopping, there, back = sum(map(rest_to_rest, align)), align[:-1], align[-1:]
    align_flown = rest_to_rest(sum(there)) + rest_to_rest(sum(back)) - settle
    v = config.process.motion.empty_travel_speed_mm_s  # the inspection's, with the gripper empty
    assert got["stopping_s"] == pytest.approx(align_stopping + sum(map(rest_to_rest, inspect)))
    assert sweep.path_mm[1] == sweep.path_mm[3] and sweep.path_mm[1][0] == sweep.path_mm[2][0]  # up the side and back
    assert got["flown_s"] == pytest.approx(align_flown + rest_to_rest(sum(inspect)))
    assert got["length_mm"] == pytest.approx(sum(align) + sum(inspect))
