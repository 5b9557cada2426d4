"""A STOP sent while a move is being staged (SPEED, POS, ORI answered, MOVEL not yet sent) keeps that move from
starting: the driver refuses it instead of sending the motion after the stop. The peer: the lines the controller fake
received on its RAPID socket."""

from __future__ import annotations

from typing import Any

import pytest
from _abb_testkit import fake_and_robot

from cellctl.ports import CartesianPose, DeviceRejected, MotionRequest


async def test_a_stop_while_a_move_is_staged_keeps_it_from_starting() -> None:
    async with fake_and_robot() as (fake, robot):
        start = await robot.read_pose(timeout_s=3.0)
        link = robot._verbs.link  # noqa: SLF001 - the stop must land between two requests of the move
        request = link.request

        async def stop_after_ori(verb: str, *args: Any, **kw: Any) -> Any:
            lines = await request(verb, *args, **kw)
            if verb == "ORI":  # the operator's Hold arrives now
                await robot.stop(timeout_s=3.0)
            return lines

        link.request = stop_after_ori
        target = CartesianPose((start.position_mm[0] + 50.0, *start.position_mm[1:]), start.quaternion_wxyz)
        with pytest.raises(DeviceRejected, match="not started: a STOP came while it was staged"):
            await robot.move(MotionRequest(target, "linear", 200.0, 30.0), timeout_s=5.0)
        del link.request
        verbs = [line.split()[1] for line in fake.server.lines_received if len(line.split()) > 1]
        assert "STOP" in verbs and not {"MOVEL", "MOVEJ"} & set(verbs[verbs.index("STOP"):]), verbs
        assert (await robot.read_pose(timeout_s=3.0)).position_mm == pytest.approx(start.position_mm, abs=1e-3)
        reached = await robot.move(MotionRequest(target, "linear", 200.0, 30.0), timeout_s=5.0)  # the next move runs
        assert reached.position_mm == pytest.approx(target.position_mm, abs=0.5)
