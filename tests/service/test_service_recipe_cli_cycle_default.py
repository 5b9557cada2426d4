"""`cellctl cycle` without --recipe runs the configuration's first recipe, whatever its name (as teach and
nine-point do), against a cell served over HTTP by uvicorn; the cycle is read back with httpx and scored
against the twin's truth."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest
from live_cell import LiveCell
from service_test_support import TOKEN, sim_toml
from shared_support import free_port

from cellctl.cli import main
from cellctl.config import load_config

pytestmark = pytest.mark.timeout(240)


def test_cycle_without_recipe_runs_the_first_recipe_of_the_configuration(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg_path = tmp_path / "cell.toml"
    cfg_path.write_text(sim_toml(free_port()).replace('name = "side-window"', 'name = "front-side"', 1))  # the first renamed
    config = load_config(cfg_path)
    assert [r.name for r in config.process.recipes] == ["front-side", "door-window"]
    with LiveCell(tmp_path / "work", config) as live:
        code = main(["--config", str(cfg_path), "cycle", "--url", live.url, "--token", TOKEN, "--start", "--part", "P1"])
        out = capsys.readouterr()
        assert code == 0, out.out + out.err
        cycles = httpx.get(f"{live.url}/cycles", timeout=10).json()
        assert [(c["recipe"], c["state"]) for c in cycles] == [("front-side", "done")]
        rec = httpx.get(f"{live.url}/cycles/{cycles[0]['id']}", timeout=10).json()
        te = rec["true_error"]
        assert all(abs(te[k]) < 0.5 for k in ("dx_mm", "dy_mm", "dz_mm")), te  # the side window's glass in its opening
