"""The verification moves without a stop (issue 19): EGM position guidance through the real ABB driver and its
fake controller, whose EGM side moves the twin's arm; scored against the twin's truth."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from service_test_support import AUTH, api_client, running_service, sim_config, to_execute

from cellctl.domain import AlarmCode

AXES_MM = ("dx_mm", "dy_mm", "dz_mm")
AXES_DEG = ("drx_deg", "dry_deg", "drz_deg")


async def _cycles(tmp_path: Path, n: int, *, before: Any = None, **overrides: Any) -> list[dict[str, Any]]:
    config = sim_config(**{"plc": {"port": 0}, "sim": {"seed": 7}, **overrides})
    out = []
    async with running_service(tmp_path, config) as service, api_client(service) as client:
        await to_execute(client)
        if before is not None:
            before(service)
        for i in range(n):
            r = await client.post("/cycle?wait=true&timeout_s=120", json={"recipe": "side-window", "part_id": f"f{i}"},
                                  headers={**AUTH, "Idempotency-Key": f"f{i}"})  # fmt: skip
            assert r.status_code in (200, 201), r.text
            out.append((await client.get(f"/cycles/{r.json()['id']}")).json())
        if before is not None:
            out[-1]["status"] = (await client.get("/status")).json()
            out[-1]["robot_moving"] = service.extras["fakes"]["robot"].robot.moving
    return out


def _moves(rec: dict[str, Any]) -> list[str]:
    figures = [s["figures"] for s in rec["steps"] if s["step"] == "compensate" and "verification_moves" in s["figures"]]
    assert figures, rec["steps"]
    return list(figures[-1]["verification_moves"])


async def test_the_verification_moves_stream_through_egm_and_the_install_holds(tmp_path: Path) -> None:
    recs = await _cycles(tmp_path, 2)
    for rec in recs:
        assert rec["state"] == "done", rec.get("error")
        moves = _moves(rec)
        # every move but a first one larger than the driver's EGM limit goes by EGM; that one by RAPID, saying why
        assert moves[-1] == "egm" and all(m == "egm" or "egm_max_correction_mm" in m for m in moves), moves
        te = rec["true_error"]
        assert all(abs(te[k]) < 0.3 for k in AXES_MM) and all(abs(te[k]) < 0.05 for k in AXES_DEG), te


async def test_without_egm_the_verification_moves_are_rapid_moves(tmp_path: Path) -> None:
    off = (await _cycles(tmp_path / "off", 1, **{"process.motion": {"verify_by_egm": False}}))[0]
    none = (await _cycles(tmp_path / "none", 1, **{"devices.robot": {"kind": "sim_abb", "egm": False}}))[0]
    assert off["state"] == none["state"] == "done", (off.get("error"), none.get("error"))
    assert set(_moves(off)) == {"rapid"}
    assert all(m.startswith("rapid (") and "egm_port" in m for m in _moves(none)), _moves(none)  # the driver says why


async def test_egm_data_lost_fails_the_cycle_with_a_robot_fault_and_the_robot_standing(tmp_path: Path) -> None:
    def lose_everything(service: Any) -> None:
        egm = service.extras["fakes"]["robot"].egm
        egm.config = type(egm.config)(**{**vars(egm.config), "egm_loss_out": 0.999})  # no datagram reaches the PC

    rec = (await _cycles(tmp_path, 1, before=lose_everything))[0]
    assert rec["state"] == "failed" and rec["result"]["error_code"] == int(AlarmCode.ROBOT_FAULT), rec.get("error")
    assert "EGM correction failed" in rec["error"] and "no EGM data" in rec["error"], rec["error"]
    assert not any(s["step"] == "install" for s in rec["steps"])  # nothing installed after a lost correction
    assert rec["robot_moving"] is False
