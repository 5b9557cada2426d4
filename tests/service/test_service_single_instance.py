"""One service per store: a second `cellctl serve` on a running cell's store leaves it untouched, and a REST
port another program holds ends `serve` with one line naming the setting (exit 1), not uvicorn's exit."""

from __future__ import annotations

import asyncio
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from service_test_support import AUTH, api_client, running_service, sim_config, sim_toml, slow_moves, to_execute

from cellctl.service import build_service
from cellctl.service.compose import ServiceError

pytestmark = pytest.mark.timeout(180)


async def test_a_second_service_on_a_running_cells_store_refuses_before_it_touches_it(tmp_path: Path) -> None:
    cfg = sim_config(plc={"enabled": False})
    async with running_service(tmp_path, cfg) as service, api_client(service) as client:
        await to_execute(client)
        slow_moves(service, 30.0)
        r = await client.post("/cycle", json={"recipe": "side-window", "part_id": "P-1"}, headers={**AUTH, "Idempotency-Key": "k"})
        cid = r.json()["cycle_id"]
        for _ in range(1000):
            if (await service.store.cycle(cid)).state.value == "running":
                break
            await asyncio.sleep(0.01)
        with pytest.raises(ServiceError, match=rf"another cellctl service \(pid {os.getpid()}\) is running on the store .*\[store\] path"):
            await build_service(cfg, workdir=tmp_path)
        assert (await service.store.cycle(cid)).state.value == "running"  # not marked interrupted by the second one
        slow_moves(service, 1.0 / 30.0)
    again = await build_service(cfg, workdir=tmp_path)  # stopped: the store is free again
    await again.stop()


def test_serve_on_a_rest_port_another_program_holds_names_the_setting(tmp_path: Path) -> None:
    with socket.socket() as squatter:
        squatter.bind(("127.0.0.1", 0))
        squatter.listen()
        config = tmp_path / "cell.toml"
        config.write_text(sim_toml(squatter.getsockname()[1], auto_calibrate=False))
        proc = subprocess.run([sys.executable, "-m", "cellctl.cli", "--config", str(config), "serve", "--workdir", str(tmp_path)],
                              capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 1, proc.stderr
    assert "the REST API cannot listen on 127.0.0.1" in proc.stderr and "[api] port" in proc.stderr
    assert "Traceback" not in proc.stderr
