"""A calibration computed offline while `cellctl serve` runs: the running cell adopts it, and the audit log says who.

Real `cellctl serve` (the uncommissioned simulated cell) and, in a subprocess with no token at all, the README's offline
path `cellctl calibrate camera --dataset DIR --workdir <the service's>`. The service's GET /calibration shows the new
version; sqlite3 on the service's audit_log finds the CLI's ``calibration.store`` entry (the OS account, ``cli:offline``,
the dataset's manifest SHA-256) chained to the service's own entries, and the service's ``calibration.version_changed``
entry for the version it adopted but did not write.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from service_test_support import AUTH, serve_to_commission, wait_up

from cellctl.calibration.dataset import Dataset
from cellctl.cli import DEFAULT_CONFIG
from cellctl.config import load_config
from cellctl.sim.commissioning import TwinCommissioning

pytestmark = pytest.mark.timeout(240)


def _board_views(dest: Path) -> Dataset:
    async def go() -> Dataset:
        twin = TwinCommissioning(load_config(DEFAULT_CONFIG), seed=11)
        try:
            return await twin.collect("camera", None, dest, views=10)
        finally:
            await twin.close()

    return asyncio.run(go())


@pytest.fixture(scope="module")
def offline_while_served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """The served cell's audit log and GET /calibration before and after an offline camera calibration into its workdir."""
    workdir = tmp_path_factory.mktemp("cell")
    ds = _board_views(tmp_path_factory.mktemp("data") / "ds")
    serve, url = serve_to_commission(workdir)
    try:
        wait_up(url, serve, workdir)
        before = httpx.get(f"{url}/calibration", headers=AUTH).json()["current"]["version"]
        env = {k: v for k, v in os.environ.items() if k != "CELLCTL_TOKEN"}
        cli = subprocess.run([sys.executable, "-m", "cellctl.cli", "--config", str(workdir / "cell.toml"), "calibrate", "camera",
                              "--dataset", str(ds.root), "--workdir", str(workdir)],
                             stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=180, env=env)  # fmt: skip
        deadline = time.monotonic() + 10
        while (after := httpx.get(f"{url}/calibration", headers=AUTH).json()["current"]["version"]) == before:
            assert time.monotonic() < deadline, cli.stdout + cli.stderr
            time.sleep(0.1)
        time.sleep(0.5)  # the service's own entry is appended on its store thread
        with sqlite3.connect(f"file:{workdir / 'var' / 'cellctl.db'}?mode=ro", uri=True) as conn:
            rows = conn.execute("SELECT seq, actor, source, action, params_json, prev_hash, hash FROM audit_log ORDER BY seq").fetchall()
        yield {"cli": cli, "before": before, "after": after, "rows": rows, "ds": ds}
    finally:
        serve.send_signal(signal.SIGINT)
        try:
            serve.wait(30)
        except subprocess.TimeoutExpired:
            serve.kill()


def test_the_clis_version_is_served_and_its_entry_names_the_os_account_and_the_dataset(offline_while_served: dict[str, Any]) -> None:
    r = offline_while_served
    assert r["cli"].returncode == 0, r["cli"].stdout + r["cli"].stderr
    assert (r["before"], r["after"]) == (None, 1)
    user = subprocess.run(["id", "-un"], capture_output=True, text=True, check=True).stdout.strip()
    (entry,) = [row for row in r["rows"] if row[3] == "calibration.store"]
    assert entry[1:3] == (user, "cli:offline")
    params = json.loads(entry[4])
    assert params["version_after"] == 1 and params["dataset"] == str(r["ds"].root)
    assert params["dataset_manifest_sha256"] == hashlib.sha256((r["ds"].root / "manifest.json").read_bytes()).hexdigest()
    # one chain: the CLI's entry links to the service's entry before it
    for prev, row in zip(r["rows"], r["rows"][1:]):
        assert row[5] == prev[6] and row[0] == prev[0] + 1


def test_the_service_audits_the_version_it_adopted_but_did_not_write(offline_while_served: dict[str, Any]) -> None:
    adopted = [row for row in offline_while_served["rows"] if row[3] == "calibration.version_changed"]
    assert len(adopted) == 1 and adopted[0][1:3] == ("system", "calibration"), offline_while_served["rows"]
    params = json.loads(adopted[0][4])
    assert (params["version_before"], params["version_after"], params["written"]) == (None, 1, "external")
    assert params["written_by"]["source"] == "cli:offline"
