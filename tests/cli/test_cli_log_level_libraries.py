"""`--log-level info` shows the cell's own lines, not asyncua's address-space chatter (~1,400 lines at each OPC UA
start); `--log-level debug` lets asyncua through again."""

from __future__ import annotations

import io
import logging
from collections.abc import Iterator
from pathlib import Path

import pytest
from service_test_support import running_service, sim_config

from cellctl.logsetup import configure_logging

pytestmark = pytest.mark.timeout(120)
LIBRARIES = ("asyncua", "pymodbus")


@pytest.fixture(autouse=True)
def _library_levels_restored() -> Iterator[None]:
    levels = {name: logging.getLogger(name).level for name in LIBRARIES}
    yield
    for name, level in levels.items():
        logging.getLogger(name).setLevel(level)


async def test_an_opcua_start_at_info_logs_no_asyncua_info_lines(tmp_path: Path) -> None:
    out = io.StringIO()
    configure_logging("info", "text", stream=out)
    config = sim_config(plc={"port": 0}, opcua={"enabled": True, "port": 0})
    async with running_service(tmp_path, config) as service:
        endpoint = service.opcua_server.endpoint
        asyncua_info = [line for line in out.getvalue().splitlines() if " INFO asyncua" in line]
    lines = out.getvalue().splitlines()
    assert f"INFO cellctl.service.compose: OPC UA server on {endpoint}" in "\n".join(lines)  # info lines do come
    assert asyncua_info == [], f"{len(asyncua_info)} asyncua info lines, e.g. {asyncua_info[:3]}"
    assert len(lines) < 40, lines


def test_debug_lets_asyncua_through_and_info_caps_it_again() -> None:
    out = io.StringIO()
    configure_logging("debug", "text", stream=out)
    logging.getLogger("asyncua.server.address_space").info("node added")
    configure_logging("info", "text", stream=out)
    logging.getLogger("asyncua.server.address_space").info("node added again")
    logging.getLogger("asyncua.server.address_space").warning("a real problem")
    logging.getLogger("pymodbus.logging").info("Server listening.")
    text = out.getvalue()
    assert "node added" in text and "node added again" not in text
    assert "WARNING asyncua.server.address_space: a real problem" in text and "INFO pymodbus.logging" in text
