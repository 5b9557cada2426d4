"""Cycle.LastResult.* as an independent asyncua client receives it: after every notification the values the client
holds are one cycle's, as its record says (REST GET /cycles/{id}), never one cycle's CycleId beside another cycle's
fields, at a requested publishing interval of 0 (publish on every change) and of 100 ms, over quick cycles queued
back to back. Where a notification carries a cycle's result, CycleId comes after that cycle's fields (it is the node
to key on: a client acting on its change already holds the rest). It holds also when each write of a result lets
other tasks run (the server's publication among them) before the next."""

from __future__ import annotations

import asyncio
import math
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
from asyncua import Client, ua
from opcua_test_support import CELL, ns_of, opcua_client, running_service, secure_config
from service_test_support import AUTH, api_client, to_execute

from cellctl.opcua.address_space import CellAddressSpace

pytestmark = pytest.mark.timeout(300)

AXES = ("dx_mm", "dy_mm", "dz_mm", "drx_deg", "dry_deg", "drz_deg")
FIELDS = ("RequestId", "Recipe", "PartId", "CarId", "Ok", "ErrorCode", "Reason", "MeasuredDeviation", "CycleTime",
          "CalibrationVersion", "FinishedAt", *(f"Measured.{k}" for k in AXES), "CycleId")  # fmt: skip
CYCLES = 5
NO_CYCLE: dict[str, Any] = {"CycleId": 0, "RequestId": "", "Recipe": "", "PartId": "", "CarId": ""}
"""What LastResult shows before the service has finished any cycle (the fields a mix would change)."""


def _expected(record: dict[str, Any]) -> dict[str, Any]:
    """The LastResult values the REST record of a finished cycle gives."""
    result = record["result"]
    measured = record["measured_deviation"]
    return {
        "CycleId": record["id"], "RequestId": record["idempotency_key"], "Recipe": record["recipe"],
        "PartId": record["part_id"], "CarId": record["car_id"] or "", "Ok": result["ok"], "ErrorCode": result["error_code"],
        "Reason": "", "MeasuredDeviation": [measured[k] for k in AXES], "CycleTime": result["cycle_time_s"],
        "CalibrationVersion": result["calibration_version"] or "",
        "FinishedAt": datetime.fromisoformat(record["finished_at"]),
        **{f"Measured.{k}": measured[k] for k in AXES},
    }  # fmt: skip


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, datetime) and isinstance(b, datetime):
        a, b = (t if t.tzinfo else t.replace(tzinfo=UTC) for t in (a, b))
        return abs((a - b).total_seconds()) < 1e-3
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float):
        return math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-12)
    return bool(a == b) and type(a) is type(b)


class Recorder:
    """One subscription on the LastResult nodes, made with asyncua's service calls; ``notifications``: every
    PublishResponse's data changes, in order, as [(field, value)] in the order the server sent them."""

    def __init__(self, client: Client, ns: int, interval_ms: float) -> None:
        self.client, self.ns, self.interval_ms = client, ns, interval_ms
        self.notifications: list[list[tuple[str, Any]]] = []
        self.revised_ms: float | None = None

    def _on_publish(self, result: ua.PublishResult) -> None:
        items = [(FIELDS[m.ClientHandle], m.Value.Value.Value if m.Value.Value is not None else None)
                 for n in result.NotificationMessage.NotificationData or [] if isinstance(n, ua.DataChangeNotification)
                 for m in n.MonitoredItems]  # fmt: skip
        if items:
            self.notifications.append(items)

    async def start(self) -> None:
        params = ua.CreateSubscriptionParameters(RequestedPublishingInterval=self.interval_ms, RequestedLifetimeCount=10000,
                                                 RequestedMaxKeepAliveCount=100, PublishingEnabled=True)  # fmt: skip
        created = await self.client.uaclient.create_subscription(params, self._on_publish)
        self.revised_ms = created.RevisedPublishingInterval
        items = [ua.MonitoredItemCreateRequest(
            ItemToMonitor=ua.ReadValueId(NodeId=ua.NodeId(f"{CELL}.Cycle.LastResult.{f}", self.ns),
                                         AttributeId=ua.AttributeIds.Value),
            MonitoringMode=ua.MonitoringMode.Reporting,
            RequestedParameters=ua.MonitoringParameters(ClientHandle=h, SamplingInterval=0.0, QueueSize=100, DiscardOldest=True),
        ) for h, f in enumerate(FIELDS)]  # fmt: skip
        results = await self.client.uaclient.create_monitored_items(
            ua.CreateMonitoredItemsParameters(SubscriptionId=created.SubscriptionId, ItemsToCreate=items,
                                              TimestampsToReturn=ua.TimestampsToReturn.Both))  # fmt: skip
        assert all(r.StatusCode.is_good() for r in results), results

    def cycles_seen(self) -> set[int]:
        return {v for items in self.notifications for f, v in items if f == "CycleId"}

    def problems(self, records: dict[int, dict[str, Any]]) -> list[str]:
        """Every notification after which the client holds fields that are not those of the CycleId it holds,
        and every notification with one cycle's result in which CycleId does not come last."""
        out: list[str] = []
        held: dict[str, Any] = {}
        for k, items in enumerate(self.notifications):
            held.update(items)
            cid = held.get("CycleId")
            assert cid == 0 or cid in records, f"notification {k}: CycleId {cid} is none of this test's cycles {sorted(records)}"
            expected = NO_CYCLE if cid == 0 else _expected(records[cid])
            wrong = {f: (held.get(f), e) for f, e in expected.items() if not _same(held.get(f), e)}
            if wrong:
                out.append(f"notification {k} ({[f for f, _ in items]}): the client holds CycleId {cid} beside other "
                           f"values (held, record's): {wrong}")  # fmt: skip
            names = [f for f, _ in items]
            if names.count("CycleId") == 1 and names[-1] != "CycleId" and held["CycleId"] in records:
                out.append(f"notification {k}: CycleId {held['CycleId']} comes before fields of its cycle: {names}")
        return out


@pytest.mark.parametrize("slow_writes", [False, True], ids=["writes", "slow-writes"])
async def test_a_subscriber_holds_one_cycles_last_result_after_every_notification(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, slow_writes: bool,
) -> None:  # fmt: skip
    if slow_writes:  # each LastResult write yields 3 ms to the event loop first, as a slower write path would
        write = CellAddressSpace.write

        async def slow_write(self: CellAddressSpace, path: str, value: Any, **kw: Any) -> bool:
            if path.startswith("Cycle/LastResult/"):
                await asyncio.sleep(0.003)
            return await write(self, path, value, **kw)

        monkeypatch.setattr(CellAddressSpace, "write", slow_write)
    async with running_service(tmp_path, secure_config()) as service, api_client(service) as http:
        async with opcua_client(service, tmp_path) as client:
            ns = await ns_of(client)
            recorders = [Recorder(client, ns, 0.0), Recorder(client, ns, 100.0)]
            for r in recorders:
                await r.start()
            await to_execute(http)
            ids: list[int] = []
            for i in range(CYCLES):  # queued back to back, as a line sends quick cycles
                body = {"recipe": ("side-window", "door-window")[i % 2], "part_id": f"LR-{i}", "car_id": f"CAR-{i}"}
                resp = await http.post("/cycle", json=body, headers={**AUTH, "Idempotency-Key": f"lr-{i}"})
                assert resp.status_code == 202, resp.text
                ids.append(resp.json()["cycle_id"])
            records: dict[int, dict[str, Any]] = {}
            for cid in ids:
                for _ in range(1800):
                    record = (await http.get(f"/cycles/{cid}")).json()
                    if record["state"] in ("done", "failed", "interrupted"):
                        break
                    await asyncio.sleep(0.1)
                assert record["state"] == "done", record
                records[cid] = record
            for _ in range(100):  # the last result's notification reaches both subscriptions
                if all(ids[-1] in r.cycles_seen() for r in recorders):
                    break
                await asyncio.sleep(0.05)

    for r in recorders:
        problems = r.problems(records)
        assert not problems, f"requested interval {r.interval_ms} ms:\n" + "\n".join(problems)
        assert r.cycles_seen() >= set(ids), (r.interval_ms, sorted(r.cycles_seen()), ids)
    assert recorders[0].revised_ms == 10.0, recorders[0].revised_ms  # 0 is revised to the fastest interval granted (10 ms)
    assert recorders[1].revised_ms == 100.0, recorders[1].revised_ms
