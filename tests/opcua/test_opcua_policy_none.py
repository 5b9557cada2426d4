"""Security policy None, tried by asyncua's own client: a server configured Sign&Encrypt only answers
discovery over None but refuses a session on it (BadSecurityPolicyRejected); a server whose config lists
"None" keeps None sessions, with the cell's roles applied on them."""

from __future__ import annotations

from pathlib import Path

import pytest
from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from opcua_test_support import VIEWER_PASSWORD, call, ns_of, opcua_client, running_service, secure_config

pytestmark = pytest.mark.timeout(60)


def _plain_client(endpoint: str, monkeypatch: pytest.MonkeyPatch) -> Client:
    """A viewer's client on a channel with policy None, mode None and no certificate, even where no endpoint
    offers it (asyncua's client would otherwise refuse to try: take the first endpoint's token policies)."""
    monkeypatch.setattr(Client, "find_endpoint", staticmethod(lambda eps, mode, uri: list(eps)[0]))
    client = Client(endpoint, timeout=5)
    client.set_user("scada")
    client.set_password(VIEWER_PASSWORD)
    return client


async def test_a_sign_and_encrypt_server_refuses_a_session_over_policy_none(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    async with running_service(tmp_path, secure_config()) as service:
        endpoint = service.opcua_server.endpoint
        # Discovery needs no security (OPC UA Part 4, 5.4): GetEndpoints over None answers, offering Sign&Encrypt only.
        endpoints = await Client(endpoint, timeout=5).connect_and_get_server_endpoints()
        assert {(e.SecurityPolicyUri, e.SecurityMode) for e in endpoints} == {
            (SecurityPolicyBasic256Sha256.URI, ua.MessageSecurityMode.SignAndEncrypt)}
        with pytest.raises(ua.uaerrors.BadSecurityPolicyRejected):
            async with _plain_client(endpoint, monkeypatch):
                pass
        monkeypatch.undo()
        # The viewer over the configured Sign&Encrypt channel is still refused an operator's method.
        async with opcua_client(service, tmp_path, user="scada", password=VIEWER_PASSWORD) as viewer:
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await call(viewer, await ns_of(viewer), "BaseStateMachine.Clear")
        assert service.orchestrator.machine.state.name == "ABORTED"
        assert not [e for e in await service.store.audit_entries(limit=100) if e.source == "opcua"]


async def test_a_server_listing_none_keeps_none_sessions_with_their_roles(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = secure_config(security_policies=["Basic256Sha256_SignAndEncrypt", "None"])
    async with running_service(tmp_path, cfg) as service:
        async with _plain_client(service.opcua_server.endpoint, monkeypatch) as viewer:
            ns = await ns_of(viewer)
            assert await viewer.get_node(ua.NodeId("cell-1.Status.StateCurrent", ns)).read_value() == 9
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await call(viewer, ns, "BaseStateMachine.Clear")
