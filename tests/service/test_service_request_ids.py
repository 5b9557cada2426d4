"""A request id names one request: its repeat gets its cycle, the same id for another glass is refused on every
interface (REST's Idempotency-Key, the PLC's cycle_req_id; OPC UA's RequestId: tests/opcua/test_opcua_cell.py)."""

from __future__ import annotations

from pathlib import Path

from service_test_support import AUTH, api_client, running_service, sim_config, slow_moves, to_execute

from cellctl.plc.register_map import PlcErrorCode


async def test_the_plc_id_of_a_running_cycle_asked_again_for_another_part_is_refused_as_in_use(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        await to_execute(client)
        slow_moves(service, 30.0)
        link = service.plc_link
        recipe_id = next(iter(service.config.process.recipe_names()))
        assert (await link.start_cycle(7, recipe_id, 100)).accepted
        assert (await link.start_cycle(7, recipe_id, 100)).accepted  # its repeat: the same cycle, nothing new
        other = await link.start_cycle(7, recipe_id, 200)  # the same id for another glass while the first runs
        assert not other.accepted and other.error_code == PlcErrorCode.ID_IN_USE
        assert other.reason is not None and "part_id" in other.reason
        cycles = (await client.get("/cycles", headers=AUTH)).json()
        assert [c["part_id"] for c in cycles] == ["100"]


async def test_a_rest_key_used_again_for_another_part_is_refused_naming_the_difference(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, api_client(service) as client:
        await to_execute(client)
        body = {"recipe": "side-window", "part_id": "P-1"}
        assert (await client.post("/cycle", json=body, headers={**AUTH, "Idempotency-Key": "k"})).status_code == 202
        r = await client.post("/cycle", json=body | {"part_id": "P-2"}, headers={**AUTH, "Idempotency-Key": "k"})
        assert r.status_code == 422 and "part_id" in r.text, r.text
