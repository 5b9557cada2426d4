"""examples/opcua_client.py, as the README gives it to a plant, installs a window on the simulated cell."""

from __future__ import annotations

import asyncio
import os
import sys
from pathlib import Path

import pytest
from opcua_test_support import PASSWORD, running_service, secure_config

REPO = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.timeout(180)


async def test_the_example_client_installs_one_window(tmp_path: Path) -> None:
    async with running_service(tmp_path, secure_config()) as service:
        env = {**os.environ, "CELLCTL_OPCUA_PASSWORD": PASSWORD}
        proc = await asyncio.create_subprocess_exec(
            sys.executable, str(REPO / "examples" / "opcua_client.py"), "--url", service.opcua_server.endpoint,
            "--part", "P-EX", "--car", "CAR-EX", "--request-id", "example-1",
            cwd=tmp_path, env=env, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT,
        )  # fmt: skip
        out, _ = await asyncio.wait_for(proc.communicate(), 120)
        text = out.decode()
        assert proc.returncode == 0, text
        record = (await service.store.cycles(limit=5))[0]
        assert (record.request.part_id, record.request.car_id, record.idempotency_key) == ("P-EX", "CAR-EX", "example-1")
        assert f"cycle {record.id}: OK" in text, text
