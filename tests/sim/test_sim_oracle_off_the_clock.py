"""The oracle's teaching (the twin's truth computed on a twin of its own, on the first cycle of each recipe) is the
twin's computing, which a real cell does not do (it reads its calibration set): it stands the cell's clock still,
so the first cycle's calibrate step takes no robot time (it counted the 1-2 s of teaching). The peer: the cycle
record's step times as GET /cycles/N gives them."""

from __future__ import annotations

from pathlib import Path

from service_test_support import AUTH, api_client, running_service, sim_config, to_execute


async def test_the_first_cycles_calibrate_step_counts_no_teaching(tmp_path: Path) -> None:
    cfg = sim_config(plc={"enabled": False}, sim={"seed": 4242})  # a seed of its own: no other test taught it already
    async with running_service(tmp_path, cfg) as service, api_client(service) as client:
        await to_execute(client)
        r = await client.post("/cycle", params={"wait": "true", "timeout_s": 120},
                              json={"recipe": "side-window", "part_id": "P-first"}, headers={**AUTH, "Idempotency-Key": "first"})
        assert r.status_code == 200 and r.json()["state"] == "done", r.text
        steps = r.json()["result"]["step_time_s"]
        assert steps["calibrate"] < 0.2, steps  # reading a calibration, not teaching one (1-2 s of computing)
