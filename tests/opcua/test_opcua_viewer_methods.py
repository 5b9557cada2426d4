"""A viewer user (a read-only SCADA) connecting with asyncua's client after an alarm was raised: it calls the
methods that change nothing (ConditionRefresh, ConditionRefresh2 replay the active alarm; GetResult answers),
while every method that changes the cell, and Acknowledge, still answers BadUserAccessDenied."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest
from asyncua import Client, ua
from opcua_test_support import (
    CELL,
    VIEWER_PASSWORD,
    call,
    client_certificate,
    nid,
    ns_of,
    opcua_client,
    secure_config,
    to_execute,
    wait_value,
)
from service_test_support import running_service, sim_config

from cellctl.domain import PackMLState
from cellctl.opcua.nodeset import METHODS

pytestmark = pytest.mark.timeout(180)
HELD = int(PackMLState.HELD)


class _Events:
    def __init__(self) -> None:
        self.got: list[Any] = []

    def event_notification(self, event: Any) -> None:
        self.got.append(event)


async def _replayed(client: Client, method: int, *, with_item: bool) -> list[str]:
    """Subscribe to alarms, call ConditionRefresh (or ConditionRefresh2 on the monitored item); the conditions replayed."""
    events = _Events()
    sub = await client.create_subscription(20, events)
    item = await sub.subscribe_alarms_and_conditions(ua.ObjectIds.Server, ua.ObjectIds.AlarmConditionType)
    args = [ua.Variant(sub.subscription_id, ua.VariantType.UInt32)]
    if with_item:
        args.append(ua.Variant(item, ua.VariantType.UInt32))
    await client.get_node(ua.ObjectIds.ConditionType).call_method(ua.NodeId(method), *args)
    for _ in range(100):
        if any(getattr(e, "ConditionName", None) for e in events.got):
            break
        await asyncio.sleep(0.05)
    await sub.delete()
    return [str(e.ConditionName) for e in events.got if getattr(e, "ConditionName", None) and getattr(e, "ActiveState/Id")]


async def test_a_viewer_refreshes_alarms_and_reads_results_but_changes_nothing(tmp_path: Path) -> None:
    strict = sim_config(plc={"enabled": False}, opcua=secure_config().opcua.model_dump(mode="json"),
                        **{"process.limits": {"max_correction_mm": 0.5}})  # fmt: skip
    async with running_service(tmp_path, strict) as service:
        cert = await client_certificate(tmp_path)
        # An operator runs a cycle that fails with alarm 1304; the cell holds, the alarm stays active.
        async with opcua_client(service, tmp_path, certificate=cert) as op:
            ns = await ns_of(op)
            await to_execute(op, ns)
            cid = await call(op, ns, "Cycle.StartCycle", "side-window", "P-BAD", "", "req-bad")
            await wait_value(op, ns, "Cycle.LastResult.CycleId", lambda v: v == cid, "the failing cycle", 120)
            await wait_value(op, ns, "Status.StateCurrent", lambda v: v == HELD, "the hold")
        async with opcua_client(service, tmp_path, user="scada", password=VIEWER_PASSWORD, certificate=cert) as viewer:
            alarm = ["1304 CORRECTION_LIMIT_EXCEEDED"]
            assert await _replayed(viewer, ua.ObjectIds.ConditionType_ConditionRefresh, with_item=False) == alarm
            assert await _replayed(viewer, ua.ObjectIds.ConditionType_ConditionRefresh2, with_item=True) == alarm
            finished, ok, code = (await call(viewer, ns, "Cycle.GetResult", "req-bad"))[:3]
            assert (finished, ok, code) == (True, False, 1304)
            # Every method that changes the cell is refused, whatever its arguments.
            mutating = [m.path.replace("/", ".") for m in METHODS if not m.read_only]
            assert "Cycle.StartCycle" in mutating and "SetUnitMode" in mutating
            for path in mutating:
                with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                    await call(viewer, ns, path)
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await call(viewer, ns, "Cycle.StartCycle", "side-window", "P-V", "", "req-viewer")
            condition = viewer.get_node(ua.NodeId(f"{CELL}.Alarms.1304_CORRECTION_LIMIT_EXCEEDED", ns))
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await condition.call_method(ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge),
                                            ua.Variant(b"any", ua.VariantType.ByteString), ua.LocalizedText("viewer"))  # fmt: skip
            # A read-only method cannot carry a mutating one into the same Call request.
            both = [ua.CallMethodRequest(ObjectId=ua.NodeId(f"{CELL}.Cycle", ns), MethodId=ua.NodeId(f"{CELL}.{p}", ns),
                                         InputArguments=[ua.Variant(a) for a in args])
                    for p, args in (("Cycle.GetResult", ["req-bad"]),
                                    ("Cycle.StartCycle", ["side-window", "P-V", "", "req-viewer"]))]  # fmt: skip
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await viewer.uaclient.call(both)
            assert await nid(viewer, ns, "Status.StateCurrent").read_value() == HELD
        assert [c.id for c in await service.store.cycles()] == [cid]  # the viewer started nothing
        active = [a for a in service.orchestrator.alarms.current() if int(a.code) == 1304]
        assert active and not any(a.acknowledged for a in active)  # and acknowledged nothing
