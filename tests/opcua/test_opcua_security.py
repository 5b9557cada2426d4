"""The OPC UA server's security as a plant expects it, tried by an independent client: one encrypted
endpoint, no anonymous session, a wrong password refused, a viewer that cannot call, an untrusted
client certificate refused, a certificate user known by name; and the configuration a hardware cell refuses."""

from __future__ import annotations

import shutil
import tomllib
from pathlib import Path

import pytest
from asyncua import Client, ua
from asyncua.crypto import uacrypto
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from opcua_test_support import (
    CLIENT_URI,
    VIEWER_PASSWORD,
    call,
    client_certificate,
    ns_of,
    opcua_client,
    running_service,
    secure_config,
)
from service_test_support import ROOT

from cellctl.config import parse_config
from cellctl.opcua.security import certificate_uri

pytestmark = pytest.mark.timeout(120)


async def _refused(endpoint: str, folder: Path, *, user: str | None, password: str | None, cert: tuple[Path, Path]) -> BaseException:
    client = Client(endpoint, timeout=5)
    client.application_uri = CLIENT_URI
    if user is not None:
        client.set_user(user)
        client.set_password(password or "")
    await client.set_security(SecurityPolicyBasic256Sha256, str(cert[0]), str(cert[1]), mode=ua.MessageSecurityMode.SignAndEncrypt)
    with pytest.raises(Exception) as err:
        async with client:
            pass
    return err.value


async def test_only_known_users_over_an_encrypted_channel(tmp_path: Path) -> None:
    async with running_service(tmp_path, secure_config()) as service:
        endpoint = service.opcua_server.endpoint
        cert = await client_certificate(tmp_path)
        # No security mode None is offered: a client asking for it finds no endpoint.
        plain = Client(endpoint, timeout=5)
        plain.set_user("operator")
        plain.set_password("sim-opcua-password-change-me")
        with pytest.raises(Exception, match="[Nn]o matching endpoints|BadSecurityPolicyRejected|BadSecurityModeRejected"):
            async with plain:
                pass
        # Anonymous and a wrong password are refused.
        anon = await _refused(endpoint, tmp_path, user=None, password=None, cert=cert)
        assert "BadIdentityTokenRejected" in repr(anon) or "BadIdentityTokenInvalid" in repr(anon), repr(anon)
        wrong = await _refused(endpoint, tmp_path, user="operator", password="not-the-password-000", cert=cert)
        assert "BadUserAccessDenied" in repr(wrong), repr(wrong)
        # A viewer reads and subscribes but may not call a method.
        async with opcua_client(service, tmp_path, user="scada", password=VIEWER_PASSWORD, certificate=cert) as viewer:
            ns = await ns_of(viewer)
            assert await viewer.get_node(ua.NodeId("cell-1.Status.StateCurrent", ns)).read_value() == 9
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await call(viewer, ns, "BaseStateMachine.Clear")
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):  # nobody writes the address space
                await viewer.get_node(ua.NodeId("cell-1.Status.StateCurrent", ns)).write_value(ua.Variant(6, ua.VariantType.Int32))
        assert service.orchestrator.machine.state.name == "ABORTED"  # the viewer changed nothing


async def test_trusted_client_certificates_and_certificate_users(tmp_path: Path) -> None:
    trusted = tmp_path / "trusted"
    trusted.mkdir()
    mes = await client_certificate(tmp_path, "mes")
    stranger = await client_certificate(tmp_path, "stranger")
    robot_user = await client_certificate(tmp_path, "line-robot-user", uri="urn:plant:line-user")
    shutil.copy(mes[0], trusted / "mes.der")
    cfg = secure_config(trusted_clients=str(trusted), users=[
        {"name": "operator", "password": "sim-opcua-password-change-me"},
        {"name": "line-cert-user", "certificate": str(robot_user[0])},
    ])  # fmt: skip
    async with running_service(tmp_path, cfg) as service:
        untrusted = await _refused(service.opcua_server.endpoint, tmp_path, user="operator",
                                   password="sim-opcua-password-change-me", cert=stranger)  # fmt: skip
        assert "BadCertificateUntrusted" in repr(untrusted) or "BadSecurityChecksFailed" in repr(untrusted), repr(untrusted)
        # The trusted client, logging in with an X.509 user certificate: its name goes into the audit log.
        client = Client(service.opcua_server.endpoint, timeout=10)
        client.application_uri = CLIENT_URI
        await client.set_security(SecurityPolicyBasic256Sha256, str(mes[0]), str(mes[1]), mode=ua.MessageSecurityMode.SignAndEncrypt)
        client.user_certificate = await uacrypto.load_certificate(robot_user[0])
        client.user_private_key = await uacrypto.load_private_key(robot_user[1])
        async with client:
            ns = await ns_of(client)
            await call(client, ns, "BaseStateMachine.Clear")
        entries = [e for e in await service.store.audit_entries(limit=100) if e.source == "opcua"]
        assert entries and entries[-1].actor == "line-cert-user", [(e.actor, e.action) for e in entries]


async def test_the_server_certificate_is_made_once_and_must_match_the_uri(tmp_path: Path) -> None:
    cfg = secure_config()
    async with running_service(tmp_path, cfg) as service:
        cert = tmp_path / "var" / "opcua" / "server-cert.der"
        first = cert.read_bytes()
        assert certificate_uri(cert) == service.opcua_server.application_uri == "urn:cellctl:cell-1"
        assert (tmp_path / "var" / "opcua" / "server-key.pem").stat().st_mode & 0o077 == 0  # the key is the service's alone
    async with running_service(tmp_path, cfg):
        assert cert.read_bytes() == first  # kept across restarts: the plant's clients trust this one
    other = secure_config(application_uri="urn:plant:another-cell")
    from cellctl.service import build_service
    from cellctl.service.compose import ServiceError

    service = await build_service(other, workdir=tmp_path)
    with pytest.raises(ServiceError, match="application_uri"):
        await service.start()


def test_a_hardware_cell_refuses_anonymous_none_and_passwords_in_the_file() -> None:
    data = tomllib.loads((ROOT / "config" / "hardware.example.toml").read_text())
    parse_config(data, "hardware.example.toml")  # as shipped: Sign&Encrypt, no anonymous, passwords from the environment
    data["opcua"].update(allow_anonymous=True, security_policies=["None"])
    data["opcua"]["users"][0] = {"name": "mes", "password": "a-password-in-the-file-123"}
    with pytest.raises(ValueError) as err:
        parse_config(data, "hardware (test)")
    text = str(err.value)
    for field in ("opcua.allow_anonymous", "opcua.security_policies", "opcua.users.0.password"):
        assert field in text, (field, text)


async def test_a_taken_port_refuses_the_start_naming_the_setting(tmp_path: Path) -> None:
    import socket

    from cellctl.service import build_service
    from cellctl.service.compose import ServiceError

    with socket.socket() as other:
        other.bind(("127.0.0.1", 0))
        other.listen()
        service = await build_service(secure_config(port=other.getsockname()[1]), workdir=tmp_path)
        with pytest.raises(ServiceError, match=r"\[opcua\] port"):
            await service.start()
    assert service.stopped  # nothing left running
