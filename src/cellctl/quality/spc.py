"""The closed loop over measured install deviations: estimate the cell's systematic offset, apply it
(bounded) to the next installs, and ask for recalibration when it drifts past a limit.

Per axis (the six figures of :class:`cellctl.domain.InstallDeviation`; mm and deg):

- **what it estimates**: the *uncompensated* deviation ``u = measured + applied``, what the cell
  would have done without the loop (the install target was moved by ``inv(offset)``, so a bias
  ``b`` measures ``b - applied``). The estimate never chases its own correction, and the offset is
  a function of the estimate, not an increment: reloading the state after a restart gives the
  same offset, never the offset applied twice.
- **start**: the estimate starts at ``min_samples`` results since the last reset, as their mean,
  sigma their standard deviation. Before that only the tolerance gate applies: a handful of
  results cannot tell an outlier from noise (with 5 results on 6 axes, a k-sigma test on their own
  spread drops a good result in 15 to 70 % of starts). Meanwhile (``warm_up_offset``) the running
  mean of the results so far is the offset, from the first result on: Grubbs' harmonic rule for
  setting a process with an unknown start offset (the n-th result moves the setting by 1/n of
  it), so a new recipe's teaching error is gone after its first install rather than its fifth. A
  wild result within tolerance moves the offset by at most tolerance / n, never past max_offset,
  and the EWMA forgets it as ``(1 - lambda)^n``. The drift checks start with the estimate: a
  bias past the drift limit is compensated up to max_offset meanwhile and alarmed at min_samples.
- **EWMA**: ``e = lambda * u + (1 - lambda) * e``; its noise is ``sigma * sqrt(lambda / (2 - lambda))``.
- **offset** for the next install: 0 within the dead band, else the working estimate clipped to
  +-max_offset. A statistical band (2 standard errors of the estimate) instead of the fixed one was
  measured and left out: on a cell without bias it spares each recipe's first installs the warm-up
  mean's noise (1.3-2.3x their mean square error), but on cells calibrated from data it leaves their
  bias in for 1-2 more installs (p99 Rz 0.0145 -> 0.0293 deg over 3 cells x 30 cycles).
- **drift**: the estimate past the drift limit (``trend``), or ``outlier_run`` results in a row
  excluded on the same side of the estimate (``step``: the cell jumped by more than the gate
  admits). Drift stays until a reset, and holds the axis: its estimate is no longer fed (nor
  gated) and its offset stays what it was when the drift was recorded, in every recipe's loop
  alike; the other axes go on. The offset never passes max_offset meanwhile. Why the EWMA
  rather than a CUSUM: the limit is about the *size* of the systematic offset (past it the
  calibration has moved and compensating it hides that), not about detecting a small shift
  early: small shifts are what the loop compensates. The EWMA is the figure that is compared with
  the bound and shown to the operator, and the step rule catches the large sudden jumps the gate
  would otherwise exclude for ever.
- **excluded** (counted, never absorbed): no measurement, an unreliable one, non-finite figures,
  an install out of tolerance, a result further than ``outlier_k * max(sigma+, sigma_floor)`` from
  the estimate on any axis, a cycle already counted. sigma: the start-up results' standard
  deviation, then a running mean turning into an EWMA (weight 0.02) of the squared residuals of
  accepted results (bounded by the gate, so robust); sigma+ raises it to its upper
  two-standard-error bound, so a sigma learnt from few results does not gate too tightly.
- **reset**: a result under another calibration-set version (the offset belongs to the old set:
  :meth:`SpcLoop.offset` gives zero under a different version), or :meth:`SpcLoop.reset`.

Pure: no I/O, no clock (``at`` is passed in), no globals.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import replace
from datetime import datetime

import numpy as np

from cellctl.config.spc import SpcConfig, drift_limit_problems
from cellctl.domain import InstallDeviation
from cellctl.geometry.pose import Pose, pose_from_xyz_fixed
from cellctl.quality.spc_state import (
    AXES,
    AxisState,
    Drift,
    DriftKind,
    Exclusion,
    SpcEvent,
    SpcRecord,
    SpcState,
    SpcUpdate,
    axis_unit,
)

SIGMA_LAMBDA = 0.02  # the noise estimate's EWMA weight: noise changes slowly (about 100 results of memory)
SIGMA_DOF = (2 - SIGMA_LAMBDA) / SIGMA_LAMBDA  # that EWMA's equivalent degrees of freedom (99)

Deviation = Mapping[str, float] | InstallDeviation


def offset_pose(offset: Mapping[str, float]) -> Pose:
    """The offset as a small pose in T: translation (dx, dy, dz) mm, rotation XYZ fixed angles (eq. 13,
    ``Rz(drz) @ Ry(dry) @ Rx(drx)``). The install target takes ``inv(offset_pose(...))``."""
    return pose_from_xyz_fixed(
        [offset["dx_mm"], offset["dy_mm"], offset["dz_mm"]],
        math.radians(offset["drz_deg"]),
        math.radians(offset["dry_deg"]),
        math.radians(offset["drx_deg"]),
    )


def _figures(what: str, values: Deviation) -> dict[str, float]:
    d = dataclasses.asdict(values) if isinstance(values, InstallDeviation) else dict(values)
    missing = [a for a in AXES if a not in d]
    if missing:
        raise ValueError(f"{what} lacks {', '.join(missing)}; it needs all of {', '.join(AXES)}")
    return {a: float(d[a]) for a in AXES}


class SpcLoop:
    """The loop under one configuration; the install tolerance is [process.tolerance]'s."""

    def __init__(self, config: SpcConfig, *, tolerance_mm: float, tolerance_deg: float) -> None:
        # A loaded configuration was refused already (ProcessConfig); this guards a loop built from parts.
        problems = drift_limit_problems(config, tolerance_mm, tolerance_deg)
        if problems:
            raise ValueError("; ".join(f"process.spc.{name} = {text}" for name, text in problems.items()))
        self.config = config
        self._tolerance = {"mm": float(tolerance_mm), "deg": float(tolerance_deg)}

    # -- per-axis settings ------------------------------------------------------------------------

    def _cfg(self, name: str, axis: str) -> float:
        return float(getattr(self.config, f"{name}_{axis_unit(axis)}"))

    def working_estimate(self, s: AxisState) -> float | None:
        """What an axis's offset follows: its estimate, or while it warms up (``warm_up_offset``) the running mean."""
        if s.estimate is not None or not self.config.warm_up_offset:
            return s.estimate
        return s.warm_up_mean

    def _offset_of(self, axis: str, state: SpcState) -> float:
        """The offset an axis applies: its working estimate beyond the dead band, within max_offset; a drifting
        axis holds the offset it had when the drift was recorded."""
        s = state.axes[axis]
        if not self.config.enabled:
            return 0.0
        if axis in state.drifting_axes:
            return s.offset
        estimate = self.working_estimate(s)
        if estimate is None or abs(estimate) <= self._cfg("dead_band", axis):
            return 0.0
        bound = self._cfg("max_offset", axis)
        return float(min(max(estimate, -bound), bound))

    def _gate(self, axis: str, sigma: float | None, dof: float | None = None) -> float:
        """How far a result may lie from the estimate: k sigmas, sigma raised to its upper
        two-standard-error bound for its ``dof`` (few results: a wider gate), never below the floor."""
        upper = (sigma or 0.0) * (1.0 + 2.0 / math.sqrt(2.0 * min(dof, SIGMA_DOF))) if dof else (sigma or 0.0)
        return self.config.outlier_k * max(upper, self._cfg("sigma_floor", axis))

    # -- reading ----------------------------------------------------------------------------------

    def offset(self, state: SpcState, calibration_version: str | int | None = None) -> dict[str, float]:
        """The offset for the next install (zeros while disabled, before the first result, or when
        ``calibration_version`` is not the state's: the offset belongs to the calibration it was learnt under;
        the cell names one by the parts its recipe's cycles use, :func:`cellctl.cell.quality_loop.calibration_key`)."""
        if calibration_version is not None and str(calibration_version) != state.calibration_version:
            return {a: 0.0 for a in AXES}
        return {a: self._offset_of(a, state) for a in AXES}

    def offset_pose(self, state: SpcState, calibration_version: str | int | None = None) -> Pose:
        """:meth:`offset` as a pose in T (:func:`offset_pose`)."""
        return offset_pose(self.offset(state, calibration_version))

    # -- changing ---------------------------------------------------------------------------------

    def reset(
        self, state: SpcState, *, at: datetime | None = None, reason: SpcEvent = SpcEvent.RESET_OPERATOR
    ) -> SpcUpdate:
        """Forget the estimate and drift (an operator's command); the calibration version stays."""
        if reason not in (SpcEvent.RESET_OPERATOR, SpcEvent.RESET_CALIBRATION):
            raise ValueError(f"a reset's reason is an operator's or a calibration change, not {reason.value}")
        previous = self.offset(state)
        fresh = self._fresh(state, state.calibration_version, reason, at)
        return SpcUpdate(fresh, self._record(fresh, None, (reason,), None, None), previous, reset=reason)

    def update(
        self,
        state: SpcState,
        deviation: Deviation | None,
        *,
        calibration_version: str | int,
        cycle_id: int | None = None,
        reliable: bool = True,
        applied: Mapping[str, float] | None = None,
        at: datetime | None = None,
    ) -> SpcUpdate:
        """Feed one cycle's measured deviation (None: nothing was installed or measured).

        ``calibration_version``: the calibration the install ran under (another than the state's resets
        the loop first). ``applied``: the offset the install really used; by default what
        :meth:`offset` gave for it. A ``cycle_id`` at or below the last one counted changes nothing
        (``record`` is None, ``excluded`` DUPLICATE).
        """
        version = str(calibration_version)
        previous = self.offset(state, version)
        if cycle_id is not None and state.last_cycle_id is not None and cycle_id <= state.last_cycle_id:
            return SpcUpdate(state, None, previous, excluded=Exclusion.DUPLICATE)
        applied_now = previous if applied is None else _figures("the applied offset", applied)
        events: list[SpcEvent] = []
        reset: SpcEvent | None = None
        if state.calibration_version is None:
            state = replace(state, calibration_version=version)
        elif state.calibration_version != version:
            reset = SpcEvent.RESET_CALIBRATION
            events.append(reset)
            state = self._fresh(state, version, reset, at)
        state = replace(state, last_cycle_id=state.last_cycle_id if cycle_id is None else cycle_id, updated_at=at)

        excluded, u = None, None
        if deviation is None:
            excluded = Exclusion.NOT_INSTALLED
        elif not reliable:
            excluded = Exclusion.UNRELIABLE
        else:
            measured = _figures("the measured deviation", deviation)
            if not all(math.isfinite(v) for v in measured.values()):
                excluded = Exclusion.NOT_FINITE
            else:
                u = {a: measured[a] + applied_now[a] for a in AXES}
                state, excluded, started = self._feed(state, measured, u)
                if started:
                    events.append(SpcEvent.ESTIMATE_STARTED)
        if excluded is not None:
            state = _count(state, excluded.value, 1)

        held = set(state.drifting_axes)  # drifting before this result: their offsets stay
        state, drift_started = self._check_drift(state, u, excluded, applied_now)
        if drift_started:
            events.append(SpcEvent.DRIFT)
        fresh = replace(state, drifting=tuple(d for d in state.drifting if d.axis in held))
        axes = {a: s if a in held else replace(s, offset=self._offset_of(a, fresh)) for a, s in state.axes.items()}
        state = replace(state, axes=axes)
        record = self._record(state, cycle_id, tuple(events), excluded, u)
        return SpcUpdate(state, record, previous, excluded, drift_started, reset)

    # -- the steps --------------------------------------------------------------------------------

    def _fresh(self, state: SpcState, version: str | None, reason: SpcEvent, at: datetime | None) -> SpcState:
        axes = {a: AxisState() for a in AXES}  # offsets are 0 until the first result
        return SpcState(
            version, axes, last_cycle_id=state.last_cycle_id, updated_at=at, reset_at=at, reset_reason=reason
        )

    def _feed(
        self, state: SpcState, measured: Mapping[str, float], u: Mapping[str, float]
    ) -> tuple[SpcState, Exclusion | None, bool]:
        """Gate one result and fold it in: (state, exclusion, whether the estimate started)."""
        tol = {a: self._tolerance[axis_unit(a)] for a in AXES}
        beyond = {a for a in AXES if abs(measured[a]) > tol[a]}
        if beyond:
            return self._runs(state, u, beyond), Exclusion.BEYOND_TOLERANCE, False
        held = set(state.drifting_axes)  # neither gated nor fed until a reset
        if not state.estimating:
            return self._warm_up(state, u, held)
        axes, dof = state.axes, state.n_samples - 1
        est = {a: float(axes[a].estimate or 0.0) for a in AXES}  # all set once estimating
        wild = {a for a in AXES if a not in held and abs(u[a] - est[a]) > self._gate(a, axes[a].sigma, dof)}
        if wild:
            return self._runs(state, u, wild), Exclusion.OUTLIER, False
        lam = self.config.ewma_lambda
        w = max(1.0 / (dof + 1), SIGMA_LAMBDA)  # a running mean at first, then an EWMA
        new = {}
        for a, s in axes.items():
            if a in held:
                new[a] = replace(s, run=0)
                continue
            assert s.estimate is not None and s.sigma is not None
            var = (u[a] - s.estimate) ** 2 * (2 - lam) / 2  # the residual also carries the estimate's own noise
            new[a] = replace(
                s,
                estimate=lam * u[a] + (1 - lam) * s.estimate,
                sigma=math.sqrt(w * var + (1 - w) * s.sigma**2),
                run=0,
            )
        return replace(state, axes=new, n_samples=state.n_samples + 1), None, False

    def _runs(self, state: SpcState, u: Mapping[str, float], failed: set[str]) -> SpcState:
        """Count gate failures in a row per axis and side (an axis that passed starts again)."""
        axes = {}
        for a, s in state.axes.items():
            if a not in failed:
                axes[a] = replace(s, run=0)
                continue
            centre = s.estimate if s.estimate is not None else 0.0
            up = u[a] > centre
            run = (s.run + 1 if s.run > 0 else 1) if up else (s.run - 1 if s.run < 0 else -1)
            axes[a] = replace(s, run=run)
        return replace(state, axes=axes)

    def _warm_up(self, state: SpcState, u: Mapping[str, float], held: set[str]) -> tuple[SpcState, None, bool]:
        """Gather start-up results; at min_samples, start the estimate from their mean, sigma from their spread.
        A held (drifting) axis gathers its own mean again, so its working estimate stays."""

        def value(a: str, s: AxisState) -> float:
            return u[a] if a not in held else (s.warm_up_mean or 0.0)

        axes = {a: replace(s, warmup=(*s.warmup, value(a, s)), run=0) for a, s in state.axes.items()}
        state = replace(state, axes=axes, n_samples=state.n_samples + 1)
        if state.n_samples < self.config.min_samples:
            return state, None, False
        x = {a: np.array(axes[a].warmup) for a in AXES}
        started = {
            a: AxisState(estimate=float(x[a].mean()), sigma=float(x[a].std(ddof=1)), offset=axes[a].offset)
            for a in AXES
        }
        return replace(state, axes=started), None, True

    def _check_drift(
        self, state: SpcState, u: Mapping[str, float] | None, excluded: Exclusion | None, applied: Mapping[str, float]
    ) -> tuple[SpcState, tuple[Drift, ...]]:
        have = {(d.axis, d.kind) for d in state.drifting}
        new: list[Drift] = []
        for a, s in state.axes.items():
            limit = self._cfg("drift_limit", a)
            if s.estimate is not None and abs(s.estimate) > limit and (a, DriftKind.TREND) not in have:
                new.append(Drift(a, DriftKind.TREND, s.estimate, limit))
            gated = excluded in (Exclusion.OUTLIER, Exclusion.BEYOND_TOLERANCE)
            if gated and u is not None and abs(s.run) >= self.config.outlier_run and (a, DriftKind.STEP) not in have:
                if excluded == Exclusion.OUTLIER:  # the gate about the estimate
                    gate, tested = self._gate(a, s.sigma, state.n_samples - 1), u[a] - float(s.estimate or 0.0)
                else:  # the install tolerance about 0, on the deviation measured (u less the offset it was installed with)
                    gate, tested = self._tolerance[axis_unit(a)], u[a] - applied[a]
                new.append(Drift(a, DriftKind.STEP, u[a], limit, gate, tested))
        return (replace(state, drifting=(*state.drifting, *new)) if new else state), tuple(new)

    def _record(
        self,
        state: SpcState,
        cycle_id: int | None,
        events: tuple[SpcEvent, ...],
        excluded: Exclusion | None,
        u: Mapping[str, float] | None,
    ) -> SpcRecord:
        return SpcRecord(
            cycle_id, state.calibration_version, events, excluded, u, state.estimate, state.offset, state.drifting_axes
        )


def _count(state: SpcState, reason: str, n: int) -> SpcState:
    excluded = dict(state.excluded)
    excluded[reason] = excluded.get(reason, 0) + n
    return replace(state, excluded=excluded)

