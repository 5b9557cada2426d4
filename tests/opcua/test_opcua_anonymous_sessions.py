"""Who a session is, tried with asyncua's own client on the simulated cell's demo [opcua] (config/sim.toml:
policies Sign&Encrypt and None, anonymous sessions allowed, a password operator).

asyncua hands the user manager the secure channel's certificate for an anonymous token too (b"" over None),
so the channel's certificate must not be taken for a certificate user: anonymous over None and over
Sign&Encrypt are anonymous; an X509 identity token is its configured user or refused; a password user
still logs in; and with allow_anonymous = false an anonymous session is refused."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import pytest
from asyncua import Client, ua
from asyncua.crypto import uacrypto
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from opcua_test_support import CLIENT_URI, PASSWORD, call, client_certificate, ns_of, running_service, wait_value
from service_test_support import ROOT, sim_config

from cellctl.service.compose import Service

pytestmark = pytest.mark.timeout(120)
ABORTED, STOPPED = 9, 2


def _demo(**opcua: Any) -> Any:
    """config/sim.toml with its [opcua] as shipped, on any free port, with these fields changed."""
    shipped = tomllib.loads((ROOT / "config" / "sim.toml").read_text(encoding="utf-8"))["opcua"]
    assert shipped["allow_anonymous"] is True and "None" in shipped["security_policies"], shipped
    return sim_config(plc={"enabled": False}, opcua={**shipped, "port": 0, **opcua})


async def _encrypted(client: Client, cert: tuple[Path, Path]) -> Client:
    client.application_uri = CLIENT_URI
    await client.set_security(SecurityPolicyBasic256Sha256, str(cert[0]), str(cert[1]), mode=ua.MessageSecurityMode.SignAndEncrypt)
    return client


async def _opcua_actors(service: Service) -> list[str]:
    return [e.actor for e in await service.store.audit_entries(limit=100) if e.source == "opcua"]


async def test_the_demo_takes_anonymous_sessions_and_keeps_its_users_apart(tmp_path: Path) -> None:
    channel = await client_certificate(tmp_path, "mes")
    known = await client_certificate(tmp_path, "scada-user", uri="urn:plant:scada-user")
    stranger = await client_certificate(tmp_path, "stranger-user", uri="urn:plant:stranger-user")
    users = [{"name": "operator", "password": PASSWORD}, {"name": "scada", "role": "viewer", "certificate": str(known[0])}]
    async with running_service(tmp_path, _demo(users=users)) as service:
        endpoint = service.opcua_server.endpoint
        # Anonymous over security None, as UaExpert's anonymous login on the demo: a session, the cell's nodes.
        async with Client(endpoint, timeout=10) as anon:
            ns = await ns_of(anon)
            assert await anon.get_node(ua.NodeId("cell-1.Status.StateCurrent", ns)).read_value() == ABORTED
            await call(anon, ns, "BaseStateMachine.Clear")
        assert await _opcua_actors(service) == ["opcua-anonymous"]
        # Anonymous over Sign&Encrypt: the channel's certificate is nobody's user certificate, still anonymous.
        async with await _encrypted(Client(endpoint, timeout=10), channel) as anon_encrypted:
            ns = await ns_of(anon_encrypted)
            assert await anon_encrypted.get_node(ua.NodeId("cell-1.Status.StateCurrent", ns)).read_value() is not None
        # A password user over None logs in as itself.
        plain = Client(endpoint, timeout=10)
        plain.set_user("operator")
        plain.set_password(PASSWORD)
        async with plain:
            ns = await ns_of(plain)
            await wait_value(plain, ns, "Status.StateCurrent", lambda v: v == STOPPED, "the anonymous Clear settles")
            await call(plain, ns, "BaseStateMachine.MachineState.Reset")
        assert (await _opcua_actors(service))[-1] == "operator"
        # An X509 identity token of a configured certificate user is that user (a viewer: no method) ...
        viewer = await _encrypted(Client(endpoint, timeout=10), channel)
        viewer.user_certificate = await uacrypto.load_certificate(known[0])
        viewer.user_private_key = await uacrypto.load_private_key(known[1])
        async with viewer:
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await call(viewer, await ns_of(viewer), "BaseStateMachine.Clear")
        # ... and one that opcua.users does not name is refused, anonymous sessions allowed or not.
        unknown = await _encrypted(Client(endpoint, timeout=10), channel)
        unknown.user_certificate = await uacrypto.load_certificate(stranger[0])
        unknown.user_private_key = await uacrypto.load_private_key(stranger[1])
        with pytest.raises(ua.uaerrors.BadUserAccessDenied):
            async with unknown:
                pass
        assert await _opcua_actors(service) == ["opcua-anonymous", "operator"]


async def test_anonymous_is_refused_when_not_allowed_even_over_none(tmp_path: Path) -> None:
    async with running_service(tmp_path, _demo(allow_anonymous=False)) as service:
        endpoint = service.opcua_server.endpoint
        with pytest.raises(ua.uaerrors.BadIdentityTokenRejected):  # the anonymous token is not offered
            async with Client(endpoint, timeout=10):
                pass
        plain = Client(endpoint, timeout=10)  # the same channel with the operator's password is a session
        plain.set_user("operator")
        plain.set_password(PASSWORD)
        async with plain:
            assert await plain.get_node(ua.NodeId("cell-1.Status.StateCurrent", await ns_of(plain))).read_value() == ABORTED
