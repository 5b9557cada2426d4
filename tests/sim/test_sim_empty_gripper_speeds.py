"""The robot moves at the empty gripper's speeds only once the gripper has let go of the glass (the twin's truth)."""

from __future__ import annotations

from pathlib import Path

import pytest

from cellctl.bench.accuracy import RunSettings, run_accuracy
from cellctl.bench.cycle_time import with_align_mode
from cellctl.config import load_config
from cellctl.ports import CartesianPose, MotionRequest
from cellctl.sim.devices import SimRobot

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("mode", ["stop_and_go", "on_the_fly"])
def test_moves_after_the_release_run_at_the_empty_speeds_and_none_with_the_glass(
    monkeypatch: pytest.MonkeyPatch, mode: str
) -> None:
    config = with_align_mode(load_config(ROOT / "config" / "sim.toml"), mode)  # type: ignore[arg-type]
    motion, sweep = config.process.motion, config.process.align.sweep
    assert motion.empty_speed_deg_s and motion.empty_speed_deg_s > motion.speed_deg_s  # the twin's cell goes faster empty
    moves: list[tuple[bool, MotionRequest]] = []  # (the twin's gripper holds a glass, what the cell asked for)
    original = SimRobot.move

    async def move(self: SimRobot, request: MotionRequest, *, timeout_s: float) -> CartesianPose:
        moves.append((self._cell.glass_on_gripper, request))
        return await original(self, request, timeout_s=timeout_s)

    monkeypatch.setattr(SimRobot, "move", move)
    run = run_accuracy(config, RunSettings(trials=2, seed=3, calibration="oracle", devices="twin"), progress=False)
    assert len(run.installed) == 2 and all(t.measured_deviation for t in run.installed), [t.reason for t in run.trials]
    held = [r for glass, r in moves if glass]
    empty = [r for glass, r in moves if not glass]
    # With the glass: never faster than its speeds, the alignment's sweep on the move included (it asks for more).
    assert sweep.speed_mm_s > motion.travel_speed_mm_s
    assert held and all(r.speed_mm_s <= motion.travel_speed_mm_s and r.speed_deg_s == motion.speed_deg_s for r in held)
    # Released: every move turns at the empty speed; the first of each cycle backs out at the back-off speed,
    # the travels run at the empty travel speed.
    assert empty and all(r.speed_deg_s == motion.empty_speed_deg_s for r in empty)
    firsts = [r for (was, _), (glass, r) in zip(moves, moves[1:]) if was and not glass]
    assert len(firsts) == 2 and all(r.speed_mm_s == motion.back_off_speed_mm_s for r in firsts)
    assert any(r.speed_mm_s == motion.empty_travel_speed_mm_s for r in empty)
