"""A step of the robot controller's EGM clock on the first leg of an on-the-fly sweep: the cycle fails, the robot
stands, no wall plane is fitted (before, the latency estimate took the step in and the glass was installed ~0.3 mm off).

The service runs the real ABB and LK-G drivers over their fakes (twin behind); the step is injected between the
fake's EGM thread and its socket, once it has sent ``TRIGGER`` datagrams (past the moves along the beam).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from service_test_support import AUTH, api_client, running_service, sim_config, to_execute

from abb_robot.egm import egm_pb2 as pb
from cellctl.cell.alarms import AlarmCode

pytestmark = [pytest.mark.realtime, pytest.mark.timeout(180)]
TRIGGER = 450
STEP_MS = 30


class _ClockStep:
    """Stands in for the fake's EGM socket: from the ``TRIGGER``-th datagram on, header.tm and feedBack.time read
    ``STEP_MS`` more (the controller's clock stepped forward)."""

    def __init__(self, sock: Any, fake: Any) -> None:
        self.sock, self.fake = sock, fake
        self.stepped: list[int] = []  # the seqnos sent with the step: the truth the test checks against

    def sendto(self, data: bytes, addr: tuple[str, int]) -> int:
        st = self.fake.egm_stream_stats
        if st is None or st.sent < TRIGGER:
            return int(self.sock.sendto(data, addr))
        m = pb.EgmRobot()
        m.ParseFromString(data)
        m.header.tm = (m.header.tm + STEP_MS) & 0xFFFFFFFF
        for part in (m.feedBack, m.planned):
            sec, ms = divmod(part.time.sec * 1000 + part.time.usec // 1000 + STEP_MS, 1000)
            part.time.sec, part.time.usec = sec, ms * 1000
        self.stepped.append(m.header.seqno)
        return int(self.sock.sendto(m.SerializeToString(), addr))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.sock, name)


async def test_a_step_of_the_robots_clock_mid_sweep_fails_the_cycle_and_stops_the_robot(tmp_path: Path) -> None:
    cfg = sim_config(**{
        "sim": {"seed": 7, "time_scale": 1.0}, "process.align": {"mode": "on_the_fly"},
        "process.align.sweep": {"feedback_stale_s": 0.5}, "plc": {"port": 0}, "process.inspect": {"enabled": False},
    })  # fmt: skip
    async with running_service(tmp_path, cfg) as service, api_client(service) as client:
        await to_execute(client)
        fake = service.extras["fakes"]["robot"]
        runner = fake.egm.stream
        step = _ClockStep(runner._args[0], fake)
        runner._args = (step, *runner._args[1:])
        r = await client.post("/cycle?wait=true&timeout_s=150", json={"recipe": "side-window", "part_id": "clock-step"},
                              headers={**AUTH, "Idempotency-Key": "clock-step"})
        rec = (await client.get(f"/cycles/{r.json()['id']}")).json()
        moving = service.orchestrator.truth.cell.arm.moving()
    assert step.stepped, "the step was not injected: the sweep ended before the fake sent TRIGGER datagrams"
    assert rec["state"] == "failed", f"a sweep with a {STEP_MS} ms step of the robot's clock was accepted: {rec.get('true_error')}"
    assert (rec.get("result") or {}).get("error_code") == int(AlarmCode.POSITION_FEEDBACK_LOST), rec.get("error")
    assert "the controller's EGM clock" in rec["error"], rec["error"]  # the operator is told why the feedback ended
    assert not moving  # the supervision stopped the robot
    align = next((s for s in rec["steps"] if s["step"] == "align"), {})
    assert "normal_B" not in align.get("figures", {}), "a wall plane was fitted"
