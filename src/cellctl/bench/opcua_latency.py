"""``cellctl bench opcua``: how long after a change of the cell an OPC UA client sees it.

The simulated cell service runs with its OPC UA server (Basic256Sha256 Sign&Encrypt, a password
user); an asyncua client in its own thread and event loop subscribes to ``Status/StateCurrent`` and
``Status/CycleStep`` at the publishing interval given. The cell is driven through Hold/Unhold pairs
(four state changes each, acting states included) and then through cycles (a change per sub-step, verification shots included).
Each change's time is taken where the state machine makes it; each notification's time where the
client receives it (same host clock). The report gives median, p95 and max per kind, and how many
took over 100 ms.
"""

from __future__ import annotations

import asyncio
import queue
import statistics
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from cellctl.bench.accuracy import bring_to_execute
from cellctl.bench.sources import run_config
from cellctl.bench.stats import percentile
from cellctl.config import CellConfig, parse_config
from cellctl.domain import MachineEvent, PackMLCommand, PackMLState
from cellctl.store import CycleRequest

TARGET_MS = 100.0
PASSWORD = "bench-opcua-password-0123456789"


def _config(base: CellConfig, workdir: Path) -> CellConfig:
    data = run_config(base, workdir=workdir, seed=1, calibration="oracle").model_dump(mode="json")
    data["opcua"] = {"enabled": True, "host": "127.0.0.1", "port": 0, "allow_anonymous": False,
                     "security_policies": ["Basic256Sha256_SignAndEncrypt"],
                     "users": [{"name": "bench", "password": PASSWORD}]}  # fmt: skip
    return parse_config(data, "bench opcua")


def _client_thread(endpoint: str, folder: Path, publish_ms: float, seen: queue.Queue[tuple[str, int, float]],
                   ready: threading.Event, stop: threading.Event, errors: list[BaseException]) -> None:  # fmt: skip
    from asyncua import Client, ua
    from asyncua.crypto import cert_gen
    from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
    from cryptography.x509.oid import ExtendedKeyUsageOID

    async def run() -> None:
        cert, key = folder / "client.der", folder / "client.pem"
        await cert_gen.setup_self_signed_certificate(key, cert, "urn:bench:client", "localhost",
                                                     [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "bench"})  # fmt: skip
        client = Client(endpoint, timeout=10)
        client.application_uri = "urn:bench:client"
        client.set_user("bench")
        client.set_password(PASSWORD)
        await client.set_security(SecurityPolicyBasic256Sha256, str(cert), str(key), mode=ua.MessageSecurityMode.SignAndEncrypt)
        async with client:
            ns = await client.get_namespace_index("urn:cellctl:opcua")
            nodes = {ua.NodeId(f"cell-1.Status.{n}", ns): n for n in ("StateCurrent", "CycleStep")}
            sub = await client.create_subscription(publish_ms)
            await sub.subscribe_data_change([client.get_node(n) for n in nodes], queuesize=100)
            ready.set()
            while not stop.is_set():
                ev = await sub.next_event(timeout=0.2)
                if ev is not None and hasattr(ev, "node"):
                    seen.put((nodes[ev.node.nodeid], int(ev.value), time.time()))

    try:
        asyncio.run(run())
    except BaseException as err:  # noqa: BLE001 - reported by the caller
        errors.append(err)
        ready.set()


def _figures(lat_ms: list[float]) -> dict[str, Any]:
    if not lat_ms:
        return {"changes": 0}
    return {"changes": len(lat_ms), "median_ms": statistics.median(lat_ms), "p95_ms": percentile(lat_ms, 95),
            "max_ms": max(lat_ms), "over_100ms": sum(v > TARGET_MS for v in lat_ms)}  # fmt: skip


def _match(changes: list[tuple[str, int, float]], seen: list[tuple[str, int, float]]) -> dict[str, list[float]]:
    """Pair each change with the first notification of the same node and value after it (in order)."""
    out: dict[str, list[float]] = {"StateCurrent": [], "CycleStep": []}
    k = 0
    for name, value, t0 in changes:
        j = k
        while j < len(seen) and not (seen[j][0] == name and seen[j][1] == value and seen[j][2] >= t0 - 0.001):
            j += 1
        if j < len(seen):
            out[name].append((seen[j][2] - t0) * 1000.0)
            k = j + 1
    return out


async def _drive(service: Any, holds: int, cycles: int, changes: list[tuple[str, int, float]], seen_q: queue.Queue[Any]) -> None:
    orch = service.orchestrator

    def on_event(ev: MachineEvent) -> None:
        now = time.time()
        if ev.state_changed:
            changes.append(("StateCurrent", int(ev.state_after), now))
        if ev.step_before != ev.step_after:
            changes.append(("CycleStep", int(ev.step_after), now))

    await bring_to_execute(orch)
    await asyncio.sleep(0.5)  # the way to Execute is not timed: let its notifications arrive before the first timed change
    unsubscribe = orch.machine.subscribe(on_event)
    try:
        for _ in range(holds):
            await orch.command(PackMLCommand.HOLD, actor="bench", source="bench")
            while orch.machine.state is not PackMLState.HELD:
                await asyncio.sleep(0.005)
            await orch.command(PackMLCommand.UNHOLD, actor="bench", source="bench")
            while orch.machine.state is not PackMLState.EXECUTE:
                await asyncio.sleep(0.005)
            await asyncio.sleep(0.05)
        for k in range(cycles):
            sub = await orch.submit_cycle(CycleRequest("side-window", f"opcua-bench-{k}", None, source="bench"),
                                          scope="bench", key=f"opcua-{k}", actor="bench")  # fmt: skip
            await orch.wait_cycle(sub.cycle.id, 120.0)
        await asyncio.sleep(0.5)  # the last notifications
    finally:
        unsubscribe()


def run_opcua_latency(base: CellConfig, *, holds: int = 20, cycles: int = 5, publish_ms: float = 10.0) -> dict[str, Any]:
    from cellctl.service import build_service

    with tempfile.TemporaryDirectory(prefix="cellctl-bench-opcua-") as tmp:
        wd = Path(tmp)
        config = _config(base, wd)
        changes: list[tuple[str, int, float]] = []
        seen_q: queue.Queue[tuple[str, int, float]] = queue.Queue()

        async def main() -> None:
            service = await build_service(config, workdir=wd)
            await service.start()
            ready, stop, errors = threading.Event(), threading.Event(), []
            th = threading.Thread(target=_client_thread, args=(service.opcua_server.endpoint, wd, publish_ms, seen_q, ready, stop, errors))
            th.start()
            try:
                await asyncio.to_thread(ready.wait, 30)
                if errors:
                    raise RuntimeError(f"the OPC UA client failed: {errors[0]!r}")
                await _drive(service, holds, cycles, changes, seen_q)
            finally:
                stop.set()
                await asyncio.to_thread(th.join, 10)
                await service.stop()

        asyncio.run(main())
        seen = []
        while not seen_q.empty():
            seen.append(seen_q.get())
    first = changes[0][2] if changes else 0.0
    seen = [n for n in seen if n[2] >= first]  # not the initial values nor the way to Execute before the changes timed
    lat = _match(changes, seen)
    return {"publishing_interval_ms": publish_ms, "state": _figures(lat["StateCurrent"]), "cycle_step": _figures(lat["CycleStep"]),
            "changes_made": len(changes), "notifications": len(seen)}  # fmt: skip


def format_opcua_latency(f: dict[str, Any]) -> str:
    lines = [f"OPC UA: a change of the cell -> an encrypted client's notification (publishing interval {f['publishing_interval_ms']:g} ms)",
             f"  {f['changes_made']} changes made, {f['notifications']} notifications received"]  # fmt: skip
    for name, label in (("state", "StateCurrent (Hold/Unhold, acting states included)"), ("cycle_step", "CycleStep (during cycles)")):
        g = f[name]
        if not g.get("changes"):
            lines.append(f"  {label}: none matched")
            continue
        lines.append(f"  {label}: {g['changes']} changes, median {g['median_ms']:.1f} ms, p95 {g['p95_ms']:.1f} ms, "
                     f"max {g['max_ms']:.1f} ms, {g['over_100ms']} over {TARGET_MS:g} ms")  # fmt: skip
    return "\n".join(lines)
