"""The glass comes to the opening from outside: the install's approach stands approach_mm in front of the
install pose along the true wall normal (T's z points into the wall), and the last move goes in at the fine speed."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from service_test_support import AUTH, api_client, running_service, sim_config, to_execute

from cellctl.domain import CycleStep
from cellctl.geometry.pose import invert_pose


async def test_the_install_approaches_from_outside_the_wall_along_its_normal(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        orch = service.orchestrator
        robot, moves = orch.robot, []
        move = robot.move

        async def recorded(request: Any, *, timeout_s: float) -> Any:
            moves.append((orch.machine.cycle_step, request))
            return await move(request, timeout_s=timeout_s)

        robot.move = recorded  # type: ignore[method-assign]
        await to_execute(client)
        r = await client.post("/cycle", params={"wait": "true"}, json={"recipe": "side-window", "part_id": "P-1"},
                              headers={**AUTH, "Idempotency-Key": "k"})  # fmt: skip
        assert r.json()["state"] == "done", r.json()
        install = [req for step, req in moves if step is CycleStep.INSTALL]
        assert [m.kind for m in install] == ["joint", "linear"]
        approach, target = (m.target.to_matrix() for m in install)
        T_true = service.extras["twin"].cell.truth().T_B_T  # type: ignore[attr-defined]
        in_T = (invert_pose(T_true)[:3, :3] @ (approach[:3, 3] - target[:3, 3]))
        a = service.config.process.motion.approach_mm
        assert in_T[2] < -0.99 * a and np.hypot(in_T[0], in_T[1]) < 0.05 * a, in_T  # out of the wall, along its normal
        assert install[1].speed_mm_s == service.config.process.motion.fine_speed_mm_s
