"""EGM configured (devices.robot has an egm_port) but refused by the controller (no UDPUC device: ERR 151): the
verification moves fall back to RAPID moves, each cycle's record says so, and the log says it once per service run
with the fix, naming a config field that really turns EGM off for the verification moves.

The simulated cell's real ABB driver on its fake controller, whose EGM side is taken away (as a controller without
the UdpUc device); the peers are the cycle records and the config loader.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import pytest
from service_test_support import AUTH, api_client, running_service, sim_config, to_execute

pytestmark = pytest.mark.timeout(240)

FIELD = "process.motion.verify_by_egm"


async def _run(tmp_path: Path, cycles: int) -> list[dict[str, Any]]:
    """``cycles`` cycles on a served cell whose controller refuses EGM; their records."""
    out = []
    async with running_service(tmp_path, sim_config(plc={"port": 0}, sim={"seed": 7})) as service, api_client(service) as client:
        assert service.config.devices.robot.egm  # the robot's driver has EGM configured
        service.extras["fakes"]["robot"].server.egm = None  # the controller has no UdpUc device
        await to_execute(client)
        for i in range(cycles):
            r = await client.post("/cycle?wait=true&timeout_s=120", json={"recipe": "side-window", "part_id": f"e{i}"},
                                  headers={**AUTH, "Idempotency-Key": f"e{i}"})  # fmt: skip
            assert r.status_code in (200, 201), r.text
            out.append((await client.get(f"/cycles/{r.json()['id']}")).json())
    return out


def _moves(rec: dict[str, Any]) -> list[str]:
    return [m for s in rec["steps"] if s["step"] == "compensate" for m in s["figures"].get("verification_moves", [])]


def _warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING and "not EGM" in r.getMessage()]


async def test_egm_refused_by_the_controller_is_logged_once_per_service_run_with_the_fix(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING)
    recs = await _run(tmp_path / "first", 2)
    refused = [m for rec in recs for m in _moves(rec) if "151 EGM_SETUP" in m]
    assert all(rec["state"] == "done" for rec in recs), [rec.get("error") for rec in recs]
    assert len(refused) >= 2 and all(m.startswith("rapid (") for m in refused), [_moves(r) for r in recs]
    (said,) = _warnings(caplog)  # several refused moves, one warning
    assert "151 EGM_SETUP" in said and "UDPUC" in said and FIELD in said, said
    section, field = FIELD.rsplit(".", 1)
    off = sim_config(**{section: {field: False}})  # the field named is a real one, and it turns EGM off
    assert off.process.motion.verify_by_egm is False

    recs = await _run(tmp_path / "second", 1)  # a new service run: said again
    assert any("151 EGM_SETUP" in m for m in _moves(recs[0]))
    assert len(_warnings(caplog)) == 2, _warnings(caplog)
