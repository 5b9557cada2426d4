"""The CLI's client against a real served cell with closed reads: the token goes on every call, a wrong token's
message names $CELLCTL_TOKEN / --token, and a malformed --url or an answer that is not JSON is one line, not a traceback."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from live_cell import LiveCell
from service_test_support import TOKEN, sim_config

from cellctl.cli import main
from cellctl.client import CellClient, ServiceError

pytestmark = pytest.mark.timeout(120)
SIM = Path(__file__).resolve().parents[2] / "config" / "sim.toml"


@pytest.fixture(scope="module")
def closed_cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The simulated cell with [api] open_reads = false, served by uvicorn on 127.0.0.1 (a free port)."""
    with LiveCell(tmp_path_factory.mktemp("closed-cell"), sim_config(plc={"enabled": False}, api={"open_reads": False})) as live:
        yield live.url


def test_status_cycle_and_bring_to_execute_send_the_token(closed_cell: str) -> None:
    client = CellClient(closed_cell, token=TOKEN)
    assert httpx.get(closed_cell + "/status").status_code == 401  # reads are closed indeed
    assert client.status()["state"]
    assert client.bring_to_execute() == "EXECUTE"
    started = client.start_cycle("side-window", "C-1", wait=False)
    assert client.cycle(started["cycle_id"])["id"] == started["cycle_id"]


def test_cellctl_status_with_a_wrong_token_names_where_the_token_comes_from(
    closed_cell: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("CELLCTL_TOKEN", raising=False)
    assert main(["status", "--config", str(SIM), "--url", closed_cell, "--token", "not-this-cells"]) == 1
    err = capsys.readouterr().err
    assert "$CELLCTL_TOKEN" in err and "--token" in err and "refused" in err, err
    assert "needs a bearer token" not in err
    assert main(["status", "--config", str(SIM), "--url", closed_cell]) == 1
    assert "no token given" in capsys.readouterr().err
    assert main(["status", "--config", str(SIM), "--url", closed_cell, "--token", TOKEN]) == 0


def test_a_malformed_url_is_one_line_naming_url(capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["status", "--config", str(SIM), "--url", "http://127.0.0.1:19x"])
    err = capsys.readouterr().err
    assert rc == 1 and "--url" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err


def test_an_answer_that_is_not_json_is_a_service_error(closed_cell: str) -> None:
    client = CellClient(closed_cell, token=TOKEN)
    with pytest.raises(ServiceError, match="not JSON"):
        client._call("GET", "/")  # the dashboard page: HTML with 200, as a proxy's login page would be
