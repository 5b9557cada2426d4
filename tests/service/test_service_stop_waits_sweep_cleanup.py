"""A PackML Stop while a sweep runs: the sweep's shielded clean-up (pose stream ended, laser storage stopped) ends
before the cycle is recorded stopped and the robot's motion halt is lifted (a cancel repeated every 0.5 s cut it loose:
the cycle was recorded 0.02 s after the Stop with the laser still storing). The peer: the REST record and the clean-up's
own end, timed by the test."""
from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any

import pytest
from service_test_support import AUTH, api_client, build_service, sim_config, to_execute

pytestmark = pytest.mark.timeout(120)


@pytest.mark.parametrize("commands", [("stop",), ("hold", "abort")], ids=["stop", "hold-then-abort"])
async def test_a_stop_waits_for_the_sweeps_clean_up(tmp_path: Path, monkeypatch: Any, commands: tuple[str, ...]) -> None:
    from cellctl.cell import sweep

    moving, cleaned = asyncio.Event(), asyncio.Event()
    real_leave = sweep._leave_nothing_running
    halted_during_cleanup: list[Any] = []

    async def long_path(run: Any, step: Any, moves: Any, stream: Any) -> None:
        moves.close()
        moving.set()
        await asyncio.Event().wait()

    service_box: list[Any] = []

    async def slow_leave(*args: Any) -> None:
        await asyncio.sleep(1.5)  # a laser read-out over the serial line takes this long
        halted_during_cleanup.append(getattr(service_box[0].orchestrator.robot, "_halted", "n/a"))
        await real_leave(*args)
        cleaned.set()

    monkeypatch.setattr(sweep, "_supervised", long_path)
    monkeypatch.setattr(sweep, "_leave_nothing_running", slow_leave)
    config = sim_config(devices={"laser": {"kind": "sim"}, "robot": {"kind": "sim"}},
                        plc={"port": 0}, **{"process.align": {"mode": "on_the_fly"}})
    service = await build_service(config, workdir=tmp_path)
    service_box.append(service)
    await service.start()
    try:
        async with api_client(service) as client:
            await to_execute(client)
            r = await client.post("/cycle", json={"recipe": "side-window", "part_id": "P-1"},
                                  headers={**AUTH, "Idempotency-Key": "k-1"})
            assert r.status_code in (200, 201, 202), r.text
            cid = r.json().get("cycle_id") or r.json().get("id")
            await asyncio.wait_for(moving.wait(), timeout=30.0)
            t0 = time.monotonic()
            # One right after the other (each answered as the state machine takes it, the clean-up still ahead): sent
            # concurrently, the abort could come first and the hold be refused in Aborting, as it should.
            answers = [await client.post(f"/commands/{c}", headers=AUTH) for c in commands]
            assert all(r.status_code == 200 for r in answers), [r.text for r in answers]
            # poll the REST record until the cycle has ended
            for _ in range(400):
                rec = (await client.get(f"/cycles/{cid}")).json()
                if rec["state"] not in ("queued", "running"):
                    break
                await asyncio.sleep(0.01)
            ended_after = time.monotonic() - t0
            status = (await client.get("/status")).json()["state"]
            was_cleaned = cleaned.is_set()
            await asyncio.wait_for(cleaned.wait(), timeout=10.0)
    finally:
        await asyncio.wait_for(service.stop(), timeout=30.0)
    assert halted_during_cleanup and halted_during_cleanup[0] not in (None, "n/a"), halted_during_cleanup  # still halted
    assert was_cleaned, (f"cycle recorded {rec['state']} ({rec.get('error')}) and the cell {status} {ended_after:.2f} s after "
                         "the Stop, while the sweep's laser/stream clean-up still ran (cut loose by the repeated cancel)")
