"""A plant's OPC UA client of cellctl, short: connect encrypted, bring the cell to Execute, install one
window by car body, print its result and every alarm event meanwhile.

    python examples/opcua_client.py --url opc.tcp://127.0.0.1:4840/cellctl --user operator \\
        --password-env CELLCTL_OPCUA_PASSWORD --part P-1 --car CAR-1

It makes its own client certificate (client-cert.der / client-key.pem in --cert-dir) on first run; a cell with
``opcua.trusted_clients`` set must have that certificate in its trusted folder. The node ids are in
docs/opcua_nodeset.md. Needs only asyncua (``pip install asyncua``).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import uuid
from pathlib import Path

from asyncua import Client, ua
from asyncua.crypto import cert_gen
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from cryptography.x509.oid import ExtendedKeyUsageOID

NS = "urn:cellctl:opcua"
EXECUTE = 6
STEPS = [("BaseStateMachine.Clear", 2), ("BaseStateMachine.MachineState.Reset", 4),
         ("BaseStateMachine.MachineState.ExecuteState.Start", 6)]  # fmt: skip


async def main(args: argparse.Namespace) -> None:
    folder = Path(args.cert_dir)
    folder.mkdir(parents=True, exist_ok=True)
    cert, key = folder / "client-cert.der", folder / "client-key.pem"
    await cert_gen.setup_self_signed_certificate(key, cert, args.app_uri, "localhost", [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "plant-client"})
    client = Client(args.url, timeout=10)
    client.application_uri = args.app_uri
    client.set_user(args.user)
    client.set_password(os.environ.get(args.password_env, ""))
    await client.set_security(SecurityPolicyBasic256Sha256, str(cert), str(key), mode=ua.MessageSecurityMode.SignAndEncrypt)
    async with client:
        ns = await client.get_namespace_index(NS)

        def node(path: str) -> ua.Node:  # type: ignore[name-defined]
            return client.get_node(ua.NodeId(f"{args.cell}.{path}", ns))

        sub = await client.create_subscription(50)
        await sub.subscribe_alarms_and_conditions(ua.ObjectIds.Server, ua.ObjectIds.AlarmConditionType)
        state = await node("Status.StateCurrent").read_value()
        print(f"cell {args.cell}: state {state}")
        if state != EXECUTE:
            for path, target in STEPS:
                method = node(path)
                parent = client.get_node(ua.NodeId(f"{args.cell}.{path.rpartition('.')[0]}", ns))
                try:
                    await parent.call_method(method.nodeid)
                except ua.uaerrors.BadInvalidState:
                    continue  # not allowed in this state: the cell is past it
                while await node("Status.StateCurrent").read_value() != target:
                    await asyncio.sleep(0.1)
        request_id = args.request_id or uuid.uuid4().hex
        cycle_id = await node("Cycle").call_method(node("Cycle.StartCycle").nodeid, args.recipe, args.part, args.car, request_id)
        print(f"cycle {cycle_id} started for part {args.part} in car {args.car} (RequestId {request_id})")
        while True:
            finished, ok, code, reason, measured, seconds = await node("Cycle").call_method(node("Cycle.GetResult").nodeid, request_id)
            ev = await sub.next_event(timeout=0.5)
            if ev is not None and hasattr(ev, "event"):
                e = ev.event
                print(f"alarm event: {e.ConditionName} active={getattr(e, 'ActiveState/Id')} acked={getattr(e, 'AckedState/Id')}: {e.Message.Text}")
            if finished:
                break
        names = ("dx mm", "dy mm", "dz mm", "drx deg", "dry deg", "drz deg")
        figures = ", ".join(f"{n} {v:+.3f}" for n, v in zip(names, measured)) or "not measured"
        print(f"cycle {cycle_id}: {'OK' if ok else f'NOT OK ({code}: {reason})'} in {seconds:.2f} s; measured {figures}")


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--url", default="opc.tcp://127.0.0.1:4840/cellctl")
    p.add_argument("--cell", default="cell-1", help="the cell's cell_id")
    p.add_argument("--user", default="operator")
    p.add_argument("--password-env", default="CELLCTL_OPCUA_PASSWORD", help="environment variable holding the password")
    p.add_argument("--app-uri", default="urn:plant:example-client", help="this client's application URI (in its certificate)")
    p.add_argument("--cert-dir", default="var/opcua-client", help="where this client keeps its certificate and key")
    p.add_argument("--recipe", default="side-window")
    p.add_argument("--part", default="P-1")
    p.add_argument("--car", default="CAR-1")
    p.add_argument("--request-id", default=None, help="idempotency key (default: a new one); repeat it to ask again")
    asyncio.run(main(p.parse_args()))
