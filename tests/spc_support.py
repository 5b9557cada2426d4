"""A cell with a known systematic deviation, run under the closed loop (cellctl.quality.spc).

The truth model: the cell installs with deviation ``bias + noise``; the loop's offset moves the
install target by ``inv(offset)``, so the measured deviation is ``bias - applied + noise``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from cellctl.config.spc import SpcConfig
from cellctl.quality import AXES, SpcLoop, SpcState, SpcUpdate, axis_unit

TOL_MM, TOL_DEG = 0.5, 1.0  # [process.tolerance] (paper: +-0.5 mm, +-1 deg)
Bias = Mapping[str, float] | Callable[[int], Mapping[str, float]]


def make_loop(config: SpcConfig | None = None) -> SpcLoop:
    return SpcLoop(config or SpcConfig(), tolerance_mm=TOL_MM, tolerance_deg=TOL_DEG)


def ewma_sd(sigma: float, lam: float) -> float:
    """The steady-state standard deviation of an EWMA of white noise ``sigma``."""
    return sigma * float(np.sqrt(lam / (2 - lam)))


@dataclass
class Run:
    """What a simulated run leaves: the final state, every update, and what was measured."""

    state: SpcState
    updates: list[SpcUpdate] = field(default_factory=list)
    measured: list[dict[str, float]] = field(default_factory=list)
    applied: list[dict[str, float]] = field(default_factory=list)

    def series(self, what: str, axis: str) -> np.ndarray:
        """``offset`` (for the next install) or ``estimate`` (nan before it starts) per update, or
        ``measured`` / ``applied`` per result."""
        if what in ("measured", "applied"):
            return np.array([m[axis] for m in getattr(self, what)])
        vals = [getattr(u.state, what)[axis] for u in self.updates]
        return np.array([np.nan if v is None else v for v in vals])


def simulate_loop(
    bias: Bias,
    sigma: tuple[float, float],
    n: int,
    config: SpcConfig | None = None,
    seed: int = 0,
    *,
    loop: SpcLoop | None = None,
    state: SpcState | None = None,
    first_cycle: int = 1,
    version: str | int = "1",
    spikes: Mapping[int, Mapping[str, float]] | None = None,
) -> Run:
    """``n`` installs of a cell deviating by ``bias`` (per axis, missing axes 0; or a function of the
    result's index) plus Gaussian noise (sigma_mm, sigma_deg), each measured and fed to the loop.
    ``spikes``: extra deviation added to the measurement of result i (a wild value)."""
    loop = loop or make_loop(config)
    run = Run(state or SpcState())
    rng = np.random.default_rng(seed)
    for i in range(n):
        b = bias(i) if callable(bias) else bias
        applied = loop.offset(run.state, version)
        noise = {a: rng.normal(0.0, sigma[0] if axis_unit(a) == "mm" else sigma[1]) for a in AXES}
        m = {a: b.get(a, 0.0) - applied[a] + noise[a] for a in AXES}
        for a, extra in (spikes or {}).get(i, {}).items():
            m[a] += extra
        up = loop.update(run.state, m, calibration_version=version, cycle_id=first_cycle + i)
        run.state = up.state
        run.updates.append(up)
        run.measured.append(m)
        run.applied.append(applied)
    return run
