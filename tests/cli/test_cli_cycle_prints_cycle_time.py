"""``cellctl cycle`` prints each cycle's cycle time as its record gives it (``result.cycle_time_s``: the robot time on
the cell's clock, what every other interface reports), not how long the CLI waited (host seconds: in simulation a
fraction of it, on a real cell the time in the queue besides). The record is read with httpx from GET /cycles/N."""

from __future__ import annotations

import asyncio
import os
import re
import sys
from pathlib import Path

import httpx
from service_test_support import AUTH, ROOT, TOKEN, running_service, served, sim_config


async def test_the_cli_prints_the_records_cycle_time(tmp_path: Path) -> None:
    async with running_service(tmp_path, sim_config(plc={"enabled": False})) as service, served(service) as url:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "cellctl.cli", "--config", str(ROOT / "config" / "sim.toml"), "cycle", "--url", url,
            "--start", "--count", "2", stdin=asyncio.subprocess.DEVNULL, stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE, env={**os.environ, "CELLCTL_TOKEN": TOKEN},
        )  # fmt: skip
        out, err = (s.decode() for s in await asyncio.wait_for(proc.communicate(), 300))
        assert proc.returncode == 0, out + err
        printed = {int(m[1]): float(m[2]) for m in re.finditer(r"cycle (\d+): done, cycle time ([\d.]+) s", out)}
        assert len(printed) == 2, out
        async with httpx.AsyncClient(base_url=url, headers=AUTH, timeout=30) as client:
            for cid, shown in printed.items():
                recorded = (await client.get(f"/cycles/{cid}")).json()["result"]["cycle_time_s"]
                assert abs(shown - recorded) <= 0.05, (cid, shown, recorded)
                assert recorded > 20.0, recorded  # a real cell's robot time, not the simulation's seconds
