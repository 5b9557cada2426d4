"""A null string argument (a Variant of type Null, or a null String) from an independent OPC UA client means
"not given", as an empty string does: a null CarId is no car id (never the text "None"); a null RequestId or
PartId is refused as an empty one is, and starts nothing."""

from __future__ import annotations

from pathlib import Path

import pytest
from asyncua import Client, ua
from opcua_test_support import call, nid, ns_of, opcua_client, secure_config, to_execute, wait_value
from service_test_support import api_client, running_service

pytestmark = pytest.mark.timeout(180)

NULLS = (ua.Variant(None), ua.Variant(None, ua.VariantType.String))
"""The two nulls a client can send for a String argument: a null Variant and a null String."""


async def _refusal(client: Client, ns: int, *args: object) -> str:
    """StartCycle with ``args`` must answer BadInvalidArgument; the refusal's reason (LastRefusal, without its time)."""
    with pytest.raises(ua.uaerrors.BadInvalidArgument):
        await call(client, ns, "Cycle.StartCycle", *args)
    return str(await nid(client, ns, "Cycle.LastRefusal").read_value()).split(" ", 1)[1]


async def test_null_arguments_are_not_given(tmp_path: Path) -> None:
    async with running_service(tmp_path, secure_config()) as service, api_client(service) as rest:
        async with opcua_client(service, tmp_path) as client:
            ns = await ns_of(client)
            await to_execute(client, ns)
            # RequestId and PartId: a null one is refused exactly as an empty one is.
            empty_request = await _refusal(client, ns, "side-window", "P-1", "", "")
            assert "RequestId is empty" in empty_request
            empty_part = await _refusal(client, ns, "side-window", "", "", "req-part")
            assert "PartId is empty" in empty_part
            for null in NULLS:
                assert await _refusal(client, ns, "side-window", "P-1", "", null) == empty_request
                assert await _refusal(client, ns, "side-window", null, "", "req-part") == empty_part
                with pytest.raises(ua.uaerrors.BadNotFound):  # no cycle is known under a null (or "None") id
                    await call(client, ns, "Cycle.GetResult", null)
            with pytest.raises(ua.uaerrors.BadNotFound):
                await call(client, ns, "Cycle.GetResult", "None")
            assert (await rest.get("/cycles")).json() == []  # none of them started a cycle
            # CarId: a null one records what an empty one does, no car id.
            ids = [await call(client, ns, "Cycle.StartCycle", "side-window", f"P-{k}", car, f"req-car-{k}")
                   for k, car in enumerate(("", *NULLS))]  # fmt: skip
            await wait_value(client, ns, "Cycle.LastResult.CycleId", lambda v: v == ids[-1], "the last cycle", 120)
            assert await nid(client, ns, "Cycle.LastResult.CarId").read_value() == ""
            for k in range(len(ids)):
                assert (await call(client, ns, "Cycle.GetResult", f"req-car-{k}"))[0] is True, k
        cars = [(await rest.get(f"/cycles/{cid}")).json()["car_id"] for cid in ids]
        assert cars[0] in (None, "") and cars == [cars[0]] * len(ids), cars
