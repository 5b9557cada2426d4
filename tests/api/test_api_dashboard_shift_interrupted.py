"""The dashboard's shift tiles count a cycle a restart interrupted (``interrupted_at`` set, no
``finished_at``) as a not OK part of the shift it ended in, as ``GET /parts`` does. Through the
running service's ``GET /dashboard/shifts``, after its start-up recovery."""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path

from service_test_support import AUTH, api_client, running_service, sim_config

from cellctl.domain import CycleStep
from cellctl.store import CellStore, CycleRequest


def _left_behind(db: Path) -> None:
    """A done cycle, a failed one, and one killed during its install (the process died)."""
    db.parent.mkdir(parents=True, exist_ok=True)
    with CellStore.open(db) as store:
        for key, end in (("done", "complete"), ("failed", "fail"), ("killed", None)):
            cid = store.submit_cycle(CycleRequest("side-window", f"P-{key}"), scope="t", key=key, actor="t").cycle.id
            store.start_cycle(cid)
            store.begin_step(cid, CycleStep.INSTALL)
            if end == "complete":
                store.complete_cycle(cid, result={"part_ok": True, "cycle_time_s": 30.0})
            elif end == "fail":
                store.fail_cycle(cid, error="install refused")


async def test_an_interrupted_install_is_a_not_ok_part_of_the_current_shift(tmp_path: Path) -> None:
    _left_behind(tmp_path / "var" / "cellctl.db")
    config = sim_config(plc={"enabled": False})
    async with running_service(tmp_path, config) as service, api_client(service) as client:
        states = sorted(c.state.value for c in await service.orchestrator.store.cycles())
        assert states == ["done", "failed", "interrupted"]  # the start-up recovery marked the killed one
        # one shift a day, starting about 12 h from now: the cycles just written are in it whatever the time of day
        starts = f"{(datetime.now(timezone.utc).hour + 12) % 24:02d}:00"
        r = await client.get("/dashboard/shifts", params={"count": 1, "starts": starts}, headers=AUTH)
        assert r.status_code == 200, r.text
        shift = r.json()["shifts"][0]
        assert (shift["good"], shift["not_ok"]) == (1, 2), shift
