"""A bearer token with a trailing CR or blank (a token file edited on Windows, `export CELLCTL_TOKEN=$(cat f)`, a
copy-paste) works, as the service strips it too; one with a control or non-ASCII character is refused in one line
naming $CELLCTL_TOKEN or --token; the token never appears in a message, not even when httpx (h11) refuses a header.
The peers: `cellctl` run by the OS (its stderr and exit status) and httpx against a real served cell (closed reads)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from collections.abc import Iterator

import httpx
import pytest
from live_cell import LiveCell
from service_test_support import ROOT, TOKEN, sim_config

from cellctl.client import CellClient, ServiceError

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def closed_cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The simulated cell with [api] open_reads = false, served on 127.0.0.1 (a free port)."""
    with LiveCell(tmp_path_factory.mktemp("token-cell"), sim_config(plc={"enabled": False}, api={"open_reads": False})) as live:
        yield live.url


def _status(url: str, *, env_token: str | None = None, arg_token: str | None = None) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("CELLCTL_TOKEN", "CELLCTL_URL")}
    if env_token is not None:
        env["CELLCTL_TOKEN"] = env_token
    args = ["--token", arg_token] if arg_token is not None else []
    return subprocess.run([sys.executable, "-m", "cellctl", "status", "--config", str(ROOT / "config" / "sim.toml"),
                           "--url", url, *args], env=env, capture_output=True, text=True, timeout=60)  # fmt: skip


@pytest.mark.parametrize("given", [TOKEN + "\r", TOKEN + " ", "\t" + TOKEN + "\r\n"])
@pytest.mark.parametrize("source", ["env", "arg"])
def test_surrounding_white_space_is_removed_and_the_token_works(closed_cell: str, given: str, source: str) -> None:
    done = _status(closed_cell, **{f"{source}_token": given})  # type: ignore[arg-type]
    assert done.returncode == 0 and done.stdout.startswith("state "), done.stderr
    assert TOKEN not in done.stdout + done.stderr


@pytest.mark.parametrize("bad", ["ö", "\x01", "\r", "\u200b"])
@pytest.mark.parametrize(("source", "named"), [("env", "$CELLCTL_TOKEN"), ("arg", "--token")])
def test_a_control_or_non_ascii_character_is_one_line_naming_the_source(
    closed_cell: str, bad: str, source: str, named: str
) -> None:  # fmt: skip
    token = TOKEN[:8] + bad + TOKEN[8:]
    done = _status(closed_cell, **{f"{source}_token": token})  # type: ignore[arg-type]
    err = done.stderr.strip()
    assert done.returncode == 1 and "Traceback" not in err and len(err.splitlines()) == 1, err
    assert err.startswith(f"error: {named} holds control or non-ASCII characters") and "printable ASCII" in err, err
    assert TOKEN[:8] not in err and TOKEN[8:] not in err and "cannot reach" not in err, err


def test_the_event_stream_takes_the_token_stripped_too(closed_cell: str, monkeypatch: pytest.MonkeyPatch) -> None:
    client = CellClient(closed_cell, token=TOKEN + "\r\n")
    kind, data = next(client.events())
    assert kind == "status" and data["state"], data
    monkeypatch.setenv("CELLCTL_TOKEN", "tök" + TOKEN)
    with pytest.raises(ServiceError, match=r"^\$CELLCTL_TOKEN holds control or non-ASCII") as err:
        CellClient(closed_cell)
    assert TOKEN not in str(err.value)


def test_a_refused_header_never_puts_the_token_in_the_message(closed_cell: str) -> None:
    """h11 quotes a header value it refuses (a CR inside): the message says what failed without the request's text."""
    client = CellClient(closed_cell, token=TOKEN)
    client._token = TOKEN + "\r"  # as a token that slipped past the check would travel
    with pytest.raises(httpx.LocalProtocolError, match="Illegal header value b'Bearer " + TOKEN):  # httpx quotes it
        client._http.get("/status", headers={"Authorization": f"Bearer {client._token}"})
    for call in (client.status, lambda: next(client.events())):
        with pytest.raises(ServiceError) as err:
            call()
        assert TOKEN not in str(err.value) and "LocalProtocolError" in str(err.value), err.value


def test_a_refused_connection_says_the_os_reason_with_or_without_a_token(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CELLCTL_TOKEN", raising=False)
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))  # bound, not listening: the OS refuses the connection
        url = f"http://127.0.0.1:{held.getsockname()[1]}"
        for token in (None, TOKEN):
            with pytest.raises(ServiceError, match=r"Connection refused.*is `cellctl serve` running") as err:
                CellClient(url, token=token).status()
            assert TOKEN not in str(err.value)
