"""The plant drives the real simulated cell through an independent OPC UA client (asyncua's), encrypted:
the PackML handshake, three cycles with an idempotent repeat, a refused command, an alarm raised and
acknowledged as an event (audited with the client's user), Modbus and REST seen from OPC UA and back."""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np
import pytest
from asyncua import ua
from opcua_test_support import (
    EXEC,
    call,
    ns_of,
    opcua_client,
    secure_config,
    to_execute,
    wait_value,
)
from plc_test_support import PlcClient
from pymodbus.client import AsyncModbusTcpClient
from service_test_support import AUTH, api_client, running_service, sim_config

from cellctl.domain import DEVIATION_KEYS, PackMLState

pytestmark = pytest.mark.timeout(240)


async def _state(client, ns: int) -> PackMLState:  # type: ignore[no-untyped-def]
    return PackMLState(await (client.get_node(ua.NodeId("cell-1.Status.StateCurrent", ns))).read_value())


async def test_the_packml_handshake_and_three_cycles_over_encrypted_opcua(tmp_path: Path) -> None:
    cfg = secure_config()
    cfg = cfg.model_copy(update={"plc": cfg.plc.model_copy(update={"enabled": True, "port": 0, "scan_period_s": 0.005})})
    async with running_service(tmp_path, cfg) as service, api_client(service) as rest:
        async with opcua_client(service, tmp_path) as client:
            ns = await ns_of(client)
            # The one endpoint is Basic256Sha256 Sign&Encrypt.
            endpoints = await client.get_endpoints()
            assert {(e.SecurityPolicyUri.rsplit("#", 1)[-1], e.SecurityMode) for e in endpoints} == {
                ("Basic256Sha256", ua.MessageSecurityMode.SignAndEncrypt)}
            # Data changes of the state, as a SCADA subscribes to them.
            sub = await client.create_subscription(20)
            await sub.subscribe_data_change([client.get_node(ua.NodeId("cell-1.Status.StateCurrent", ns))], queuesize=50)
            assert await _state(client, ns) is PackMLState.ABORTED
            # A command the state model forbids: refused with BadInvalidState, nothing moves.
            with pytest.raises(ua.uaerrors.BadInvalidState):
                await call(client, ns, f"{EXEC}.Start")
            assert await _state(client, ns) is PackMLState.ABORTED
            assert "Start" in await client.get_node(ua.NodeId("cell-1.Cycle.LastRefusal", ns)).read_value()
            with pytest.raises(ua.uaerrors.BadInvalidState):  # not a cycle while the cell is aborted
                await call(client, ns, "Cycle.StartCycle", "side-window", "P-0", "", "req-early")
            # Clear, Reset, Start: the three nested state machines follow (OPC 30050 numbers).
            for path, settled in (("BaseStateMachine.Clear", PackMLState.STOPPED),
                                  ("BaseStateMachine.MachineState.Reset", PackMLState.IDLE),
                                  (f"{EXEC}.Start", PackMLState.EXECUTE)):  # fmt: skip
                await call(client, ns, path)
                await wait_value(client, ns, "Status.StateCurrent", lambda v, s=settled: v == int(s), f"{path} settles")
            seen = []
            while (ev := await sub.next_event(timeout=1.0)) is not None:
                seen.append(ev.value)
            assert PackMLState.CLEARING in seen and PackMLState.STARTING in seen and seen[-1] == PackMLState.EXECUTE, seen
            numbers = [await client.get_node(ua.NodeId(f"cell-1.{m}.CurrentState.Number", ns)).read_value()
                       for m in ("BaseStateMachine", "BaseStateMachine.MachineState", EXEC)]  # fmt: skip
            assert numbers == [19, 18, 6]  # Cleared / Running / Execute
            execute = await client.get_node(ua.NodeId(f"cell-1.{EXEC}.CurrentState", ns)).read_value()
            assert execute.Text == "Execute"
            # Three cycles; the second request is repeated and answers the same cycle.
            requests = [("req-1", "P-100", "CAR-A"), ("req-2", "P-101", "CAR-A"), ("req-2", "P-101", "CAR-A"), ("req-3", "P-102", "CAR-B")]
            ids = []
            for req, part, car in requests:
                ids.append(await call(client, ns, "Cycle.StartCycle", "side-window", part, car, req))
                done = await wait_value(client, ns, "Cycle.LastResult.CycleId", lambda v, i=ids[-1]: v == i, f"{req} finishes", 60)
                assert done == ids[-1]
            assert ids[1] == ids[2] and len(set(ids)) == 3, ids
            listed = (await rest.get("/cycles")).json()
            assert sorted(c["id"] for c in listed) == sorted(set(ids))  # the repeat started nothing
            # The last result over OPC UA is the REST record's, and the twin's truth says it is right.
            rec = (await rest.get(f"/cycles/{ids[-1]}")).json()
            last = {k: await client.get_node(ua.NodeId(f"cell-1.Cycle.LastResult.{k}", ns)).read_value()
                    for k in ("Ok", "ErrorCode", "PartId", "CarId", "RequestId", "Recipe", "MeasuredDeviation", "CalibrationVersion")}
            assert (last["PartId"], last["CarId"], last["RequestId"], last["Recipe"]) == ("P-102", "CAR-B", "req-3", "side-window")
            assert last["Ok"] is True and last["ErrorCode"] == 0
            assert np.allclose(last["MeasuredDeviation"], [rec["measured_deviation"][k] for k in DEVIATION_KEYS])
            truth = rec["true_error"]
            assert abs(truth["dx_mm"]) < 0.5 and abs(truth["dy_mm"]) < 0.5, truth
            assert np.allclose(last["MeasuredDeviation"][:3], [truth[k] for k in ("dx_mm", "dy_mm", "dz_mm")], atol=0.1)
            assert last["CalibrationVersion"] == str(rec["result"]["calibration_version"] or "")  # the oracle's set has none
            finished, ok, code, _reason, measured, cycle_time = await call(client, ns, "Cycle.GetResult", "req-2")
            assert finished and ok and code == 0 and len(measured) == 6 and cycle_time > 0
            with pytest.raises(ua.uaerrors.BadNotFound):
                await call(client, ns, "Cycle.GetResult", "req-never")
            assert await client.get_node(ua.NodeId("cell-1.Admin.ProcessedCount", ns)).read_value() == 3
            # A cycle started over Modbus appears in OPC UA.
            modbus = AsyncModbusTcpClient("127.0.0.1", port=service.plc_server.port, timeout=2, retries=1)  # type: ignore[attr-defined]
            assert await modbus.connect()
            plc = PlcClient(modbus, cfg.plc.float_word_order, unit_id=cfg.plc.unit_id)
            try:
                await plc.write(recipe_id=1, part_id=777, cycle_req_id=9001, cycle_request=1)
                await wait_value(client, ns, "Cycle.LastResult.RequestId", lambda v: v == "9001", "the PLC's cycle", 60)
                assert await client.get_node(ua.NodeId("cell-1.Cycle.LastResult.PartId", ns)).read_value() == "777"
            finally:
                modbus.close()
            # Stop over OPC UA: the state machines leave Running.
            await call(client, ns, "BaseStateMachine.MachineState.Stop")
            await wait_value(client, ns, "Status.StateCurrent", lambda v: v == int(PackMLState.STOPPED), "Stop settles")
            numbers = [await client.get_node(ua.NodeId(f"cell-1.{m}.CurrentState.Number", ns)).read_value()
                       for m in ("BaseStateMachine", "BaseStateMachine.MachineState", EXEC)]  # fmt: skip
            assert numbers == [19, 2, 0]
        # Every command and cycle was audited with the OPC UA user's name.
        audit = await service.store.audit_entries(limit=500)
        by_opcua = [e for e in audit if e.source == "opcua"]
        assert by_opcua and {e.actor for e in by_opcua} == {"operator"}, [(e.actor, e.action) for e in by_opcua]


async def test_an_alarm_is_an_event_acknowledged_from_the_client_and_audited(tmp_path: Path) -> None:
    # A correction limit far below the car bodies' spread: the cycle fails with alarm 1304 and the cell holds.
    cfg = secure_config()
    strict = sim_config(plc={"enabled": False}, opcua=cfg.opcua.model_dump(mode="json"), **{"process.limits": {"max_correction_mm": 0.5}})
    async with running_service(tmp_path, strict) as service, opcua_client(service, tmp_path) as client:
        ns = await ns_of(client)
        await to_execute(client, ns)
        sub = await client.create_subscription(20)
        await sub.subscribe_alarms_and_conditions(ua.ObjectIds.Server, ua.ObjectIds.AlarmConditionType)
        cid = await call(client, ns, "Cycle.StartCycle", "side-window", "P-BAD", "CAR-X", "req-bad")
        await wait_value(client, ns, "Cycle.LastResult.CycleId", lambda v: v == cid, "the failing cycle")
        assert await client.get_node(ua.NodeId("cell-1.Cycle.LastResult.Ok", ns)).read_value() is False
        assert await client.get_node(ua.NodeId("cell-1.Cycle.LastResult.ErrorCode", ns)).read_value() == 1304
        assert await client.get_node(ua.NodeId("cell-1.Admin.StopReason.ID", ns)).read_value() == 1304
        await wait_value(client, ns, "Status.StateCurrent", lambda v: v == int(PackMLState.HELD), "the hold")
        raised = None
        while raised is None:
            ev = await sub.next_event(timeout=10)
            assert ev is not None, "no alarm event"
            e = ev.event
            if "1304" in str(e.ConditionName) and getattr(e, "ActiveState/Id") is True:
                raised = e
        assert getattr(raised, "AckedState/Id") is False and raised.Retain is True and raised.Severity >= 600
        # Unhold is gated until the alarm is acknowledged; acknowledge it with the standard method.
        with pytest.raises(ua.uaerrors.BadInvalidState):
            await call(client, ns, f"{EXEC}.Unhold")
        condition = client.get_node(raised.NodeId)
        with pytest.raises(ua.uaerrors.BadEventIdUnknown):  # an EventId that is not the condition's latest
            await condition.call_method(ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge),
                                        ua.Variant(b"stale", ua.VariantType.ByteString), ua.LocalizedText("no"))  # fmt: skip
        await condition.call_method(ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge),
                                    ua.Variant(raised.EventId, ua.VariantType.ByteString), ua.LocalizedText("seen, glass checked"))  # fmt: skip
        acked = None
        while acked is None:
            ev = await sub.next_event(timeout=10)
            assert ev is not None, "no acknowledged event"
            if ev.event.NodeId == raised.NodeId and getattr(ev.event, "AckedState/Id") is True:
                acked = ev.event
        # The cell itself says who acknowledged: the OPC UA user, audited with the comment.
        alarm = next(a for a in service.orchestrator.alarms.recent() + service.orchestrator.alarms.current() if int(a.code) == 1304)
        assert alarm.ack_by == "operator"
        audit = [e for e in await service.store.audit_entries(limit=500) if e.action == "alarm.acknowledge"]
        assert audit and audit[-1].actor == "operator" and audit[-1].source == "opcua"
        assert audit[-1].params["comment"] == "seen, glass checked"
        await call(client, ns, f"{EXEC}.Unhold")
        await wait_value(client, ns, "Status.StateCurrent", lambda v: v == int(PackMLState.EXECUTE), "unhold")


async def test_a_cycle_started_over_opcua_is_the_cells_own_record(tmp_path: Path) -> None:
    """REST lists it with its car body and its source; a restart keeps the RequestId's answer."""
    cfg = secure_config()
    async with running_service(tmp_path, cfg) as service, api_client(service) as rest:
        r = None
        for cmd in ("clear", "reset", "start"):
            r = await rest.post(f"/commands/{cmd}", headers=AUTH)
            assert r.status_code == 200, r.text
            for _ in range(200):
                if not (await rest.get("/status")).json()["state"].endswith("ING"):
                    break
                await asyncio.sleep(0.01)
        async with opcua_client(service, tmp_path) as client:
            ns = await ns_of(client)
            cid = await call(client, ns, "Cycle.StartCycle", "side-window", "P-REST", "CAR-REST", "req-rest")
            await wait_value(client, ns, "Cycle.LastResult.CycleId", lambda v: v == cid, "the cycle")
        rec = (await rest.get(f"/cycles/{cid}")).json()
        assert (rec["part_id"], rec["car_id"], rec["state"]) == ("P-REST", "CAR-REST", "done"), rec
        assert rec["source"] == "opcua"
    async with running_service(tmp_path, cfg) as service, opcua_client(service, tmp_path) as client:  # the same store, after a restart
        ns = await ns_of(client)
        assert await call(client, ns, "Cycle.StartCycle", "side-window", "P-REST", "CAR-REST", "req-rest") == cid
        assert await client.get_node(ua.NodeId("cell-1.Cycle.LastResult.CycleId", ns)).read_value() == cid
        with pytest.raises(ua.uaerrors.BadInvalidArgument):  # the same RequestId for another glass: not the first's cycle
            await call(client, ns, "Cycle.StartCycle", "side-window", "P-OTHER", "CAR-REST", "req-rest")
        assert "req-rest" in await client.get_node(ua.NodeId("cell-1.Cycle.LastRefusal", ns)).read_value()
