"""The twin's teaching from the truth is done once per process for a config and seed, and handed out as copies."""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from service_test_support import sim_config

import cellctl.sim.oracle as oracle
from cellctl.config import CellConfig
from cellctl.sim.rig import SimRig


@dataclass(frozen=True, eq=False)
class _Taught:
    seed: int
    working_distance_mm: float
    T0: np.ndarray

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _Taught) and (self.seed, self.working_distance_mm) == (
            other.seed, other.working_distance_mm) and np.array_equal(self.T0, other.T0)


@pytest.fixture
def teachings(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Each teaching's seed, in order; the memo emptied before and after."""
    taught: list[int] = []

    def teach(rig: SimRig, config: CellConfig, *, repeats: int = 8) -> _Taught:
        taught.append(rig.cell.seed)
        return _Taught(rig.cell.seed, config.process.working_distance_mm, np.eye(4))

    monkeypatch.setattr(oracle, "oracle_calibration", teach)
    monkeypatch.setattr(oracle, "_TAUGHT", type(oracle._TAUGHT)())
    return taught


def test_a_config_and_seed_are_taught_once_and_each_caller_gets_its_own_copy(teachings: list[int]) -> None:
    cfg = sim_config()
    first = oracle.taught_once(cfg, 3)
    second = oracle.taught_once(cfg, 3)
    assert teachings == [3]
    assert first == second and first is not second
    first.T0[0, 3] = 99.0  # a caller that changes its copy changes nobody else's
    assert oracle.taught_once(cfg, 3).T0[0, 3] == 0.0
    # sections teaching never reads (the PLC's port, the store's place) do not teach anew
    assert oracle.taught_once(sim_config(plc={"port": 0}, store={"path": "elsewhere.db"}), 3) == second
    assert teachings == [3]


def test_a_change_to_what_teaching_reads_or_another_seed_teaches_anew(teachings: list[int]) -> None:
    base = sim_config()
    oracle.taught_once(base, 1)
    moved = sim_config(process={"working_distance_mm": base.process.working_distance_mm + 50.0})
    assert oracle.taught_once(moved, 1).working_distance_mm == base.process.working_distance_mm + 50.0
    oracle.taught_once(base, 2)
    oracle.taught_once(sim_config(sim={"seed": 7}), 1)  # the sim section is read: its changes count too
    assert teachings == [1, 1, 2, 1]


def test_callers_at_once_wait_for_one_teaching(teachings: list[int], monkeypatch: pytest.MonkeyPatch) -> None:
    teach = oracle.oracle_calibration
    entered = threading.Event()

    def slow(rig: SimRig, config: CellConfig, *, repeats: int = 8) -> Any:
        entered.set()
        threading.Event().wait(0.3)
        return teach(rig, config)

    monkeypatch.setattr(oracle, "oracle_calibration", slow)
    cfg = sim_config()
    out: list[Any] = []
    threads = [threading.Thread(target=lambda: out.append(oracle.taught_once(cfg, 4))) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10.0)
    assert entered.is_set() and teachings == [4] and len(out) == 3 and out[0] == out[1] == out[2]
