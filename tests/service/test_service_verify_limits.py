"""After the first verification moves, each further one is bounded by [process.limits] max_verify_step_mm/_deg:
by then the corner moves by the robot's repeatability, and a larger step means the image or the robot is wrong."""

from __future__ import annotations

from pathlib import Path

from service_test_support import AUTH, api_client, running_service, sim_config, to_execute


async def test_a_verification_step_beyond_its_limit_fails_the_cycle_naming_the_limit(tmp_path: Path) -> None:
    cfg = sim_config(plc={"enabled": False}, **{"process.verify": {"min_shots": 3, "max_shots": 4},
                                                "process.limits": {"max_verify_step_mm": 1e-6}})  # fmt: skip
    async with running_service(tmp_path, cfg) as service, api_client(service) as client:
        await to_execute(client)
        r = await client.post("/cycle", params={"wait": "true"}, json={"recipe": "side-window", "part_id": "P-1"},
                              headers={**AUTH, "Idempotency-Key": "k"})  # fmt: skip
        rec = r.json()
        assert rec["state"] == "failed", rec
        assert rec["result"]["error_code"] == 1304, rec["result"]  # correction limit exceeded
        assert "verification shooting pose moves" in rec["error"] and "the limits are 1e-06 mm" in rec["error"], rec["error"]
        assert rec["install_started_at"] is None  # refused before the install
