"""A simulated cell whose start is refused (here: a folder where the store's file belongs) leaves none of its
drivers' protocol fakes behind: no LK-G pseudo-terminal or its link, no fake controller's thread."""

from __future__ import annotations

import tempfile
import threading
from pathlib import Path

import pytest
from service_test_support import sim_config

from cellctl.service import build_service
from cellctl.service.compose import ServiceConfigError

FAKE_THREADS = ("fake LK-G", "fake-abb-controller", "fake-egm-robot")  # the names the fakes give their threads


def _fake_threads() -> set[threading.Thread]:
    return {t for t in threading.enumerate() if t.name.startswith(FAKE_THREADS)}


async def test_a_refused_start_stops_the_lkg_and_abb_fakes_it_had_started(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    temp = tmp_path / "temp"  # where the LK-G fake makes its link's folder: watched for what is left in it
    temp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    (tmp_path / "store").mkdir()
    cfg = sim_config(store={"path": str(tmp_path / "store")})
    assert (cfg.devices.laser.kind, cfg.devices.robot.kind) == ("sim_keyence_lkg", "sim_abb")
    before = _fake_threads()
    with pytest.raises(ServiceConfigError, match=r"\[store\] path .* is a folder"):
        await build_service(cfg, workdir=tmp_path)
    assert sorted(p.name for p in temp.iterdir()) == []
    assert [t.name for t in _fake_threads() - before if t.is_alive()] == []
