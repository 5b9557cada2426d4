"""Once a drift is recorded on an axis, the closed loop holds that axis's estimate and offset until a reset, in every
recipe's loop alike (alarm 1313 says "the loop stops following it"), and the alarm gives a step against the gate its
results failed. Known truth: two recipes' loops learnt a cell with a set bias and scatter; then the cell steps by a
known amount on Y, and the later results lie where the step put them."""

from __future__ import annotations

from pathlib import Path

import pytest
from spc_support import make_loop, simulate_loop

from cellctl.cell.alarms import AlarmManager
from cellctl.cell.events import EventHub
from cellctl.cell.packml import PackMLMachine
from cellctl.cell.quality_loop import InstallQualityLoop
from cellctl.config import load_config
from cellctl.domain import Alarm, AlarmCode, InstallDeviation
from cellctl.quality import AXES, Drift, DriftKind, SpcState
from cellctl.store import AsyncCellStore

ROOT = Path(__file__).resolve().parents[2]
BIAS = {"dx_mm": 0.1, "dy_mm": 0.06}  # what both recipes' installs carry before the step
STEP = 0.38  # mm on Y: the camera mount turned (the twin's 0.05 deg about x)


def _feed(loop, state: SpcState, u: dict[str, float], cycle: int):  # type: ignore[no-untyped-def]
    """One result whose uncompensated deviation is ``u``: measured = u - the offset the install used."""
    applied = loop.offset(state, "1")
    measured = {a: u.get(a, 0.0) - applied[a] for a in AXES}
    return loop.update(state, measured, calibration_version="1", cycle_id=cycle)


@pytest.mark.parametrize("sigma_mm", [0.05, 0.02])  # a wide gate (0.05 mm scatter) and a narrow one
def test_a_step_holds_the_axis_estimate_and_offset_while_other_axes_go_on(sigma_mm: float) -> None:
    loop = make_loop()
    state = simulate_loop(BIAS, (sigma_mm, 0.003), 60, seed=3, loop=loop).state
    held_offset, held_estimate = state.offset["dy_mm"], state.estimate["dy_mm"]
    assert held_offset == pytest.approx(BIAS["dy_mm"], abs=0.03)  # learnt before the step
    after = BIAS["dy_mm"] + STEP
    ups = []
    for k in range(3):  # three results past any gate: a step
        ups.append(_feed(loop, state, {**BIAS, "dy_mm": after}, 61 + k))
        state = ups[-1].state
    (drift,) = [d for u in ups for d in u.drift_started]
    assert (drift.axis, drift.kind) == ("dy_mm", DriftKind.STEP) and drift.value == pytest.approx(after, abs=0.05)
    # later results that the wide gate admits (0.15 mm past the estimate: within 4 sigmas of 0.05 mm):
    # the old loop folded them in and followed the step up to max_offset; a held axis does not
    x_before = state.estimate["dx_mm"]
    for k in range(30):
        state = _feed(loop, state, {"dx_mm": BIAS["dx_mm"] + 0.02, "dy_mm": held_estimate + 0.15}, 64 + k).state
        assert state.offset["dy_mm"] == held_offset and state.estimate["dy_mm"] == held_estimate, k
        assert loop.offset(state, "1")["dy_mm"] == held_offset
    # the other axes still learn: x followed its +0.02 mm change
    assert state.estimate["dx_mm"] == pytest.approx(x_before + 0.02, abs=0.005)
    assert state.drifting_axes == ("dy_mm",)
    assert drift.gate is not None and drift.gate < STEP  # the gate the step's results failed
    # until the operator's reset
    assert not loop.reset(state).state.drifting and loop.reset(state).state.offset["dy_mm"] == 0.0


async def _drift_on_y(tmp_path: Path, dy: list[float]) -> tuple[Alarm, Drift, float]:
    """The first recipe's loop fed the results ``dy`` (mm on Y, the truth before the loop's offset): alarm 1313, the
    drift it records and the offset Y holds."""
    config = load_config(ROOT / "config" / "sim.toml")
    store = await AsyncCellStore.open(tmp_path / "cell.db")
    try:
        alarms = AlarmManager(PackMLMachine(), robot_moving=lambda: False)
        loop = InstallQualityLoop(config, store, alarms, EventHub())
        recipe = loop.first_recipe
        for k, truth in enumerate(dy):
            offset = loop.offset_for_next(recipe, {"version": 7})
            seen = InstallDeviation(0.0, truth - offset["dy_mm"], 0.0, 0.0, 0.0, 0.0)
            _, up = await loop.after_cycle(k + 1, seen, recipe=recipe, calibration="7", applied=offset)
            await loop.raise_drift(k + 1, up, recipe)
        (alarm,) = [a for a in alarms.active() if a.code == AlarmCode.SPC_DRIFT]
        (drift,) = loop.states[recipe].drifting
        return alarm, drift, loop.states[recipe].offset["dy_mm"]
    finally:
        await store.close()


async def test_alarm_1313_gives_a_step_against_its_gate_and_the_offset_it_holds(tmp_path: Path) -> None:
    dy = [0.06 + 0.01 * ((k * 7) % 5 - 2) for k in range(40)] + [0.06 + STEP] * 3  # scatter, then the step
    alarm, drift, held = await _drift_on_y(tmp_path, dy)
    assert drift.gate is not None
    assert drift.tested is not None and abs(drift.tested - STEP) < 0.03  # the jump from the estimate the gate refused
    assert f"dy_mm step of +{drift.tested:.3f} mm (gate +-{drift.gate:.3g} mm)" in alarm.message, alarm.message
    assert f"offset held at {held:+.3f} mm" in alarm.message and "(limit" not in alarm.message
    assert "the loop stops following it" in alarm.message


@pytest.mark.parametrize("jump_mm", [-0.20, +0.70])  # past the outlier gate about the estimate; past the install tolerance
async def test_alarm_1313_gives_the_figure_its_gate_refused(tmp_path: Path, jump_mm: float) -> None:
    """A cell that learnt a +0.15 mm bias on Y, then steps by ``jump_mm``: the alarm's step is that jump (what the gate
    refused: the distance from the estimate, or the measured deviation), beyond its gate, not the deviation without the
    loop (-0.05 mm for the first: a "step" inside its own gate)."""
    alarm, drift, _ = await _drift_on_y(tmp_path, [0.15 + 0.02 * ((k * 7) % 5 - 2) for k in range(40)] + [0.15 + jump_mm] * 3)
    assert drift.gate is not None and drift.tested is not None
    assert abs(drift.tested - jump_mm) < 0.03 and abs(drift.tested) > drift.gate, (drift, alarm.message)
    assert f"dy_mm step of {drift.tested:+.3f} mm (gate +-{drift.gate:.3g} mm)" in alarm.message, alarm.message
