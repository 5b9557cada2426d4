"""A relative [[opcua.users]] password_file is taken from the service's work folder (`serve --workdir`), as the
OPC UA certificates are, whatever the process's current folder; a missing one is named by its absolute path.
The peer: asyncua's client logs in with the password written there."""

from __future__ import annotations

import os
import secrets
from pathlib import Path

import pytest
from asyncua import Client, ua
from opcua_test_support import ns_of, running_service, secure_config

from cellctl.config import CellConfig, ConfigError
from cellctl.config.api import TokenUnavailable
from cellctl.config.opcua import OpcUaUser
from cellctl.service import build_service
from cellctl.service.compose import ServiceError

pytestmark = pytest.mark.timeout(120)


def _password_file_config() -> CellConfig:
    return secure_config(security_policies=["None"], users=[{"name": "mes", "password_file": "opc-password"}])


def _folders(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, *, password: str | None = None) -> tuple[Path, Path]:
    """The work folder (with the password file, if given) and another one the test runs from."""
    workdir, elsewhere = tmp_path / "work", tmp_path / "elsewhere"
    workdir.mkdir()
    elsewhere.mkdir()
    if password is not None:
        (workdir / "opc-password").write_text(password + "\n")
        os.chmod(workdir / "opc-password", 0o600)
    monkeypatch.chdir(elsewhere)  # started from another folder, as `serve --workdir` may be
    return workdir, elsewhere


async def test_a_relative_password_file_is_read_from_the_workdir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    password = secrets.token_urlsafe(32)
    workdir, elsewhere = _folders(tmp_path, monkeypatch, password=password)
    async with running_service(workdir, _password_file_config()) as service:
        client = Client(service.opcua_server.endpoint, timeout=10)
        client.set_user("mes")
        client.set_password(password)
        async with client:
            assert await client.get_node(ua.NodeId("cell-1.Status.StateCurrent", await ns_of(client))).read_value() == 9
    assert not (elsewhere / "opc-password").exists() and (workdir / "var" / "opcua" / "server-key.pem").is_file()


async def test_a_missing_password_file_is_named_by_its_absolute_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    workdir, elsewhere = _folders(tmp_path, monkeypatch)
    service = await build_service(_password_file_config(), workdir=workdir)
    with pytest.raises(ServiceError) as err:
        await service.start()
    assert f"opcua.users 'mes': password_file: {workdir / 'opc-password'} does not exist" in str(err.value), err.value
    user = OpcUaUser(name="mes", password_file=Path("opc-password"))
    with pytest.raises(TokenUnavailable, match=f"password_file: {elsewhere / 'opc-password'} does not exist"):
        user.secret()  # no work folder given: the current folder's, said in full


def test_the_rooted_section_reads_the_password_before_the_server_starts(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``OpcUaConfig.rooted(workdir)``: what `serve` and `config check --secrets` read the passwords from."""
    from cellctl.config.loader import check_tokens

    password = secrets.token_urlsafe(32)
    workdir, elsewhere = _folders(tmp_path, monkeypatch, password=password)
    config = _password_file_config()
    with pytest.raises(ConfigError, match=f"{elsewhere / 'opc-password'} does not exist"):
        check_tokens(config)  # not rooted: the current folder's, named in full
    rooted = config.opcua.rooted(workdir)
    assert rooted.users[0].password_file == workdir.resolve() / "opc-password"
    assert rooted.users[0].secret() == password
    check_tokens(config.model_copy(update={"opcua": rooted}))
    absolute = secure_config(users=[{"name": "mes", "password_file": str(workdir / "opc-password")}]).opcua
    assert absolute.rooted(elsewhere) is absolute  # nothing relative: the same section
