"""The wall plan's read-out time of the laser's storage (``cellctl config check``): what the LK-G's ``AO``
reply really puts on the serial line (the protocol fake's bytes), at the configured baud."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from cellctl.commissioning.wall_plan import readout_s_per_reading, wall_plan
from cellctl.config import parse_config
from keyence_lkg.fake import FakeLkgController

ROOT = Path(__file__).resolve().parents[2]


def _config(name: str, **laser: object) -> object:
    data = tomllib.loads((ROOT / "config" / name).read_text())
    data["devices"]["laser"].update(laser)
    return parse_config(data, name)


def _bits_per_stored_reading() -> float:
    """Bits on the line per reading of an AO reply from the fake controller (8N1: ten per character)."""
    with FakeLkgController("LK-G3001", lambda: 351.234) as fake:
        fake.mode = "communication"
        assert fake._handle("SW,CI,1,00500,0")[0] == "SW,CI"
        fake.mode = "general"
        fake._handle("AS")
        while fake.storage.storing:
            fake.sample_storage(fake.storage.started_at + 1.0)
        reply = fake._handle("AO,1")[0]
    assert reply.count(",") == 500
    return 10.0 * (len(reply) + 1) / 500  # the reply and its CR


@pytest.mark.parametrize("baud", [9600, 115200])
def test_a_real_lkg_reads_out_at_its_baud(baud: int) -> None:
    config = _config("hardware.example.toml", baud=baud)
    assert readout_s_per_reading(config) == pytest.approx(_bits_per_stored_reading() / baud, rel=0.01)  # type: ignore[arg-type]


def test_the_plan_counts_every_reading_stored_from_start_to_stop() -> None:
    config = _config("sim.toml")
    plan = wall_plan(config)  # type: ignore[arg-type]
    stored = plan.sweep_s / config.process.align.sweep.storage_cycle_s  # type: ignore[attr-defined]
    assert plan.readout_s == pytest.approx(stored * _bits_per_stored_reading() / 115200, rel=0.01)
    assert plan.sweep_readings < stored  # the fit uses the legs' readings; all of them are read out
