"""An independent OPC UA client (asyncua's) against the real simulated cell service, over Basic256Sha256
Sign&Encrypt with its own certificate, as a plant's MES or SCADA would connect."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

from asyncua import Client, ua
from asyncua.crypto import cert_gen
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from cryptography.x509.oid import ExtendedKeyUsageOID
from service_test_support import running_service, sim_config

from cellctl.config import CellConfig
from cellctl.service.compose import Service

CELLCTL_NS = "urn:cellctl:opcua"
PASSWORD = "sim-opcua-password-change-me"
VIEWER_PASSWORD = "viewer-password-0123456789"
CLIENT_URI = "urn:plant:test-mes"
CELL = "cell-1"
EXEC = "BaseStateMachine.MachineState.ExecuteState"


def secure_config(**opcua: Any) -> CellConfig:
    """The simulated cell with OPC UA as a hardware cell runs it: Sign&Encrypt only, no anonymous sessions."""
    fields: dict[str, Any] = {
        "enabled": True, "port": 0, "security_policies": ["Basic256Sha256_SignAndEncrypt"], "allow_anonymous": False,
        "users": [{"name": "operator", "password": PASSWORD},
                  {"name": "scada", "role": "viewer", "password": VIEWER_PASSWORD}],
    }  # fmt: skip
    fields.update(opcua)
    return sim_config(plc={"enabled": False}, opcua=fields)


async def client_certificate(folder: Path, name: str = "mes", uri: str = CLIENT_URI) -> tuple[Path, Path]:
    """A client certificate and key of our own (DER, PEM), as a plant's client has."""
    cert, key = folder / f"{name}-cert.der", folder / f"{name}-key.pem"
    await cert_gen.setup_self_signed_certificate(key, cert, uri, "localhost", [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": name})
    return cert, key


@contextlib.asynccontextmanager
async def opcua_client(
    service: Service, folder: Path, *, user: str | None = "operator", password: str | None = PASSWORD,
    certificate: tuple[Path, Path] | None = None, uri: str = CLIENT_URI,
) -> AsyncIterator[Client]:  # fmt: skip
    cert, key = certificate or await client_certificate(folder, uri=uri)
    client = Client(service.opcua_server.endpoint, timeout=10)
    client.application_uri = uri
    if user is not None:
        client.set_user(user)
        client.set_password(password or "")
    await client.set_security(SecurityPolicyBasic256Sha256, str(cert), str(key), mode=ua.MessageSecurityMode.SignAndEncrypt)
    async with client:
        yield client


def nid(client: Client, ns: int, path: str) -> Any:
    return client.get_node(ua.NodeId(f"{CELL}.{path}", ns))


async def ns_of(client: Client) -> int:
    return int(await client.get_namespace_index(CELLCTL_NS))


async def call(client: Client, ns: int, path: str, *args: Any) -> Any:
    """Call the method at ``path`` on its parent object (as a client does)."""
    parent, _, _ = path.rpartition(".")
    obj = nid(client, ns, parent) if parent else client.get_node(ua.NodeId(CELL, ns))
    return await obj.call_method(ua.NodeId(f"{CELL}.{path}", ns), *args)


async def wait_value(client: Client, ns: int, path: str, check: Callable[[Any], bool], what: str, timeout_s: float = 30.0) -> Any:
    """Poll a node until ``check(value)`` (bounded)."""
    node = nid(client, ns, path)
    deadline = asyncio.get_running_loop().time() + timeout_s
    value: Any = None
    while asyncio.get_running_loop().time() < deadline:
        value = await node.read_value()
        if check(value):
            return value
        await asyncio.sleep(0.05)
    raise AssertionError(f"{what}: {path} is {value!r} after {timeout_s} s")


async def to_execute(client: Client, ns: int) -> None:
    """Clear, Reset, Start over OPC UA, each waited out until its state has settled."""
    for path, settled in (("BaseStateMachine.Clear", 2), ("BaseStateMachine.MachineState.Reset", 4), (f"{EXEC}.Start", 6)):
        await call(client, ns, path)
        await wait_value(client, ns, "Status.StateCurrent", lambda v, s=settled: v == s, f"{path} settles")


__all__ = ["running_service", "secure_config"]
