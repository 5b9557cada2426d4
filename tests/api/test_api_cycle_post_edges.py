"""POST /cycle edge cases: a ?wait=true that times out says the cycle's state now; a blank Idempotency-Key is a 422."""

from __future__ import annotations

from pathlib import Path

from service_test_support import AUTH, api_client, running_service, sim_config, slow_moves, to_execute


async def test_a_wait_that_times_out_answers_the_state_get_cycles_shows(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as svc, api_client(svc) as c:
        await to_execute(c)
        slow_moves(svc, 20.0)
        r = await c.post("/cycle?wait=true&timeout_s=1.5", json={"recipe": "side-window", "part_id": "W-1"},
                         headers={**AUTH, "Idempotency-Key": "w1"})  # fmt: skip
        now = (await c.get(f"/cycles/{r.json()['cycle_id']}")).json()["state"]
        slow_moves(svc, 1 / 20.0)
        assert r.status_code == 202 and now == "running"
        assert r.json()["state"] == now, r.text


async def test_a_key_of_white_space_only_is_a_422_naming_the_header(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as svc, api_client(svc) as c:
        await to_execute(c)
        for key in (b"\xa0", b"\xa0\xa0", b"\t"):  # U+00A0 is legal obs-text in a header
            r = await c.post("/cycle", json={"recipe": "side-window", "part_id": "K-1"}, headers={**AUTH, "Idempotency-Key": key})
            assert r.status_code == 422, (key, r.status_code, r.text)
            assert "Idempotency-Key" in r.json()["detail"], r.text
        assert (await c.get("/cycles")).json() == []
