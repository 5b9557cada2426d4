"""An interrupted cycle's reason tells the requester how to request it again: with a new request id, named as
each interface names it, because the same id answers the interrupted cycle and installs nothing."""

from __future__ import annotations

from pathlib import Path
from unittest import mock

import pytest
from service_test_support import sim_config

from cellctl.api.app import create_app
from cellctl.cell.tags import CycleStep
from cellctl.opcua.nodeset import METHODS
from cellctl.plc.register_map import register
from cellctl.store import CellStore, CycleRequest, CycleState


def _key_names() -> tuple[str, str, str]:
    """The idempotency key's name on REST (the OpenAPI header), the PLC (its register) and OPC UA (StartCycle's input)."""
    doc = create_app(mock.MagicMock(), sim_config(plc={"enabled": False}).api, mock.MagicMock()).openapi()
    params = doc["paths"]["/cycle"]["post"]["parameters"]
    rest = next(p["name"] for p in params if p["in"] == "header" and "key" in p["name"].lower())
    start = next(m for m in METHODS if m.path == "Cycle/StartCycle")
    opcua = next(a.name for a in start.inputs if "Request" in a.name)
    return rest, register("cycle_req_id").name, opcua


def _interrupted(db: Path, *, step: CycleStep | None) -> tuple[int, str]:
    """A cycle left queued (step None) or running in ``step`` by a service that stopped; after recovery, (id, reason)."""
    with CellStore.open(db) as store:
        cid = store.submit_cycle(CycleRequest("side-window-A", "P-1", "CAR-1"), scope="plc", key="42", actor="plc").cycle.id
        if step is not None:
            store.start_cycle(cid)
            store.begin_step(cid, step)
    with CellStore.open(db) as store:
        store.recover()
        record = store.cycle(cid)
        assert record.state == CycleState.INTERRUPTED
        return cid, record.error or ""


@pytest.mark.parametrize("step", [None, CycleStep.ALIGN], ids=["queued", "before-install"])
def test_the_reason_says_to_request_it_again_with_a_new_id(tmp_path: Path, step: CycleStep | None) -> None:
    db = tmp_path / "cell.db"
    cid, reason = _interrupted(db, step=step)
    assert "request it again with a new request id" in reason, reason
    for name in _key_names():
        assert name in reason, (name, reason)
    with CellStore.open(db) as store:
        # What the text warns of: the same id answers the interrupted cycle; a new one makes a new cycle.
        same = store.submit_cycle(CycleRequest("side-window-A", "P-1", "CAR-1"), scope="plc", key="42", actor="plc")
        assert not same.created and same.cycle.id == cid and same.cycle.state == CycleState.INTERRUPTED
        new = store.submit_cycle(CycleRequest("side-window-A", "P-1", "CAR-1"), scope="plc", key="43", actor="plc")
        assert new.created and new.cycle.id != cid and new.cycle.state == CycleState.QUEUED


def test_after_the_install_began_it_still_says_never_repeated(tmp_path: Path) -> None:
    _, reason = _interrupted(tmp_path / "cell.db", step=CycleStep.INSTALL)
    assert "never repeated" in reason and "request it again" not in reason, reason
