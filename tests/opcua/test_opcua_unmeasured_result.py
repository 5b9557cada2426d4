"""LastResult.Measured.* seen by an independent asyncua client: a cycle that measured nothing gives BadNoData (no
value), not a Good 0.0 that reads as a perfect install; the next measured cycle gives Good values again, the record's."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from asyncua import Client, ua
from opcua_test_support import EXEC, call, ns_of, nid, opcua_client, running_service, secure_config, to_execute, wait_value
from service_test_support import AUTH, api_client

from cellctl.domain import DEVIATION_KEYS


async def _cycle(http: Any, part_id: str) -> dict[str, Any]:
    r = await http.post("/cycle?wait=true&timeout_s=90", json={"recipe": "side-window", "part_id": part_id},
                        headers={**AUTH, "Idempotency-Key": f"opcua-{part_id}"})  # fmt: skip
    assert r.status_code == 200, r.text
    return dict(r.json())


async def _recover(client: Client, ns: int) -> None:
    """Back to Execute over OPC UA from where the failure left the cell (Held, Stopped or Aborted: PackTags 11, 2, 9)."""
    state = await wait_value(client, ns, "Status.StateCurrent", lambda v: v in (2, 9, 11), "the failure's stop settles")
    if state == 9:
        await to_execute(client, ns)
        return
    steps = [(f"{EXEC}.Unhold", 6)] if state == 11 else [("BaseStateMachine.MachineState.Reset", 4), (f"{EXEC}.Start", 6)]
    for path, settled in steps:
        await call(client, ns, path)
        await wait_value(client, ns, "Status.StateCurrent", lambda v, s=settled: v == s, f"{path} settles")


async def _measured(client: Client, ns: int, cycle_id: int) -> dict[str, ua.DataValue]:
    """The six Measured.* nodes' DataValues (status included) once LastResult shows ``cycle_id``."""
    await wait_value(client, ns, "Cycle.LastResult.CycleId", lambda v: v == cycle_id, f"LastResult of cycle {cycle_id}")
    return {k: await nid(client, ns, f"Cycle.LastResult.Measured.{k}").read_data_value(raise_on_bad_status=False) for k in DEVIATION_KEYS}


async def test_the_measured_figures_of_an_unmeasured_cycle_are_bad_no_data_and_good_again_once_measured(tmp_path: Path) -> None:
    async with running_service(tmp_path, secure_config()) as service, api_client(service) as http:
        async with opcua_client(service, tmp_path) as client:
            ns = await ns_of(client)
            await to_execute(client, ns)
            laser = service.extras["fakes"]["laser"]
            laser.silence(count=None)  # the cycle fails in align: nothing is measured
            try:
                failed = await _cycle(http, "G-UNMEASURED")
            finally:
                laser.speak()
            assert failed["state"] == "failed" and failed["measured_deviation"] is None, failed
            unmeasured = await _measured(client, ns, failed["id"])
            array = await nid(client, ns, "Cycle.LastResult.MeasuredDeviation").read_data_value()

            assert (await http.post("/alarms/acknowledge-all", headers=AUTH)).status_code == 200
            await _recover(client, ns)
            done = await _cycle(http, "G-MEASURED")
            assert done["state"] == "done" and done["measured_deviation"] is not None, done
            measured = await _measured(client, ns, done["id"])
            try:
                await nid(client, ns, "Cycle.LastResult.Measured.dx_mm").read_value()
            except ua.UaStatusCodeError as err:
                raise AssertionError(f"a measured cycle's dx_mm reads as an error: {err}") from err

    for k, dv in unmeasured.items():
        assert dv.StatusCode.value == ua.StatusCodes.BadNoData, (k, dv)
        assert dv.Value is None or dv.Value.Value is None, (k, dv)  # a Bad value is null (OPC UA Part 4, 7.7.1)
    assert array.StatusCode.is_good() and array.Value.Value == []  # the array says "not measured" as documented
    for k, dv in measured.items():
        assert dv.StatusCode.is_good(), (k, dv)
        assert dv.Value.Value == done["measured_deviation"][k], (k, dv.Value.Value, done["measured_deviation"])
