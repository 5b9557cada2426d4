"""The closed loops over measured install results, as the cell runs them (issue 16), one per recipe.

:class:`cellctl.quality.SpcLoop` is the math; this keeps each recipe's state in the store (a restart
never loses an offset nor applies it twice), gives each cycle the offset its recipe's install takes
out, feeds it the cycle's measured deviation afterwards, writes every change of an offset, every
reset and the start of a drift to the audit trail, raises alarm 1313 when a drift starts, and
publishes the loops' state for /status and the dashboard.

One loop per recipe because each recipe's install pose (g_Pos_0) is taught on its own: its bias is
its own, and one loop fed by a mix would average the recipes' biases and fit none of them. A loop is
kept under its recipe's name (never its place in ``[[process.recipes]]``) and learnt under the
calibration parts its recipe's cycles use (:func:`calibration_key`): another recipe's new teaching
leaves it alone.
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import replace
from datetime import datetime, timezone
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from cellctl.cell.alarms import AlarmManager
from cellctl.cell.events import EventHub
from cellctl.config.schema import CellConfig
from cellctl.domain import AlarmCode, InstallDeviation
from cellctl.geometry.pose import Pose
from cellctl.quality import (
    AXES,
    Drift,
    DriftKind,
    SpcLoop,
    SpcState,
    SpcUpdate,
    axis_unit,
    offset_pose,
    state_from_dict,
    state_to_dict,
)
from cellctl.store import AsyncCellStore

if TYPE_CHECKING:
    from cellctl.inspection import MeasuredDeviation

log = logging.getLogger(__name__)

ACTOR = "spc"


class InstallQualityLoop:
    """The SPC loops of one cell, one per recipe, with their persisted states.

    Args:
        config: the cell's configuration (``[process.spc]``, ``[process.tolerance]``, the recipes).
        store, alarms, events: where the states, the alarm and the live updates go.
    """

    def __init__(self, config: CellConfig, store: AsyncCellStore, alarms: AlarmManager, events: EventHub) -> None:
        p = config.process
        self.config = p.spc
        self.loop = SpcLoop(p.spc, tolerance_mm=p.tolerance.position_mm, tolerance_deg=p.tolerance.orientation_deg)
        self.store = store
        self.alarms = alarms
        self.events = events
        self.recipes = [r.name for r in p.recipes]
        self.states: dict[str, SpcState] = {name: SpcState() for name in self.recipes}

    @property
    def first_recipe(self) -> str:
        return self.recipes[0]

    def known(self, recipe: str) -> str:
        """``recipe``, the name its loop is kept under; KeyError for a recipe not configured."""
        if recipe not in self.states:
            raise KeyError(f"no recipe {recipe!r} in [[process.recipes]] (the recipes are: {', '.join(self.recipes)})")
        return recipe

    async def load(self) -> None:
        """Take up the states the store kept, by recipe name (the offsets survive a restart and a new order of
        the recipes); a loop of a recipe no longer configured stays in the store, unused. A loop kept unnamed
        (before loops were named) becomes the first recipe's, once."""
        saved = await self.store.spc_states(first_recipe=self.first_recipe)
        for name in self.recipes:
            state = saved.get(name)
            if state is not None:
                self.states[name] = state_from_dict(state)

    @staticmethod
    def no_offset() -> dict[str, float]:
        """The offset of an install the loop does not correct: zeros on every axis."""
        return dict.fromkeys(AXES, 0.0)

    def offset_for_next(self, recipe: str, calibration: Mapping[str, Any]) -> dict[str, float]:
        """The offset (six figures, mm and deg) the next install of ``recipe`` takes out under ``calibration`` (the
        source's reference for that recipe); zeros when none applies."""
        key = calibration_key(calibration)
        state = self.states[recipe]
        if key != state.calibration_version and state.calibration_version == str(calibration.get("version")):
            # Learnt (by a cellctl that keyed loops by the set's version) under the set in use now: the same parts.
            self.states[recipe] = state = replace(state, calibration_version=key)
        return self.loop.offset(state, key)

    @staticmethod
    def offset_as_pose(offset: dict[str, float]) -> Pose | None:
        """The offset as a pose in T, or None when it is zero (the install then is exactly as before)."""
        if all(v == 0.0 for v in offset.values()):
            return None
        return offset_pose(offset)

    async def after_cycle(
        self,
        cycle_id: int,
        measured: InstallDeviation | None,
        *,
        recipe: str,
        calibration: str,
        applied: dict[str, float],
        reliable: bool = True,
    ) -> tuple[dict[str, Any], SpcUpdate]:
        """Feed one cycle's result to its recipe's loop, learnt under ``calibration`` (:func:`calibration_key`);
        persist, audit and publish. Returns the record's ``spc`` fields.

        Raise the drift alarm with :meth:`raise_drift` once the cycle's record is written.
        """
        now = datetime.now(timezone.utc)
        self.known(recipe)
        up = self.loop.update(
            self.states[recipe], measured, calibration_version=calibration, cycle_id=cycle_id,
            applied=applied, at=now, reliable=reliable,
        )  # fmt: skip
        if up.record is not None:
            await self.store.save_spc(state_to_dict(up.state), up.record.as_entry(), at=now, recipe=recipe)
        self.states[recipe] = up.state
        if up.offset_changed or up.reset is not None or up.drift_started:
            await self.store.append_audit(
                actor=ACTOR, source="cell", action="spc.update", cycle_id=cycle_id,
                params={
                    "recipe": recipe,
                    "events": [e.value for e in up.events],
                    "offset_before": dict(up.previous_offset),
                    "offset_after": dict(up.state.offset),
                    "estimate": dict(up.state.estimate),
                    "drifting": list(up.state.drifting_axes),
                },
            )  # fmt: skip
        fields = {
            "recipe": recipe,
            "applied_offset": dict(applied),
            "estimate": dict(up.state.estimate),
            "next_offset": dict(up.state.offset) if self.config.enabled else {k: 0.0 for k in applied},
            "drifting_axes": list(up.state.drifting_axes),
            "samples": up.state.n_samples,
            "excluded": None if up.excluded is None else up.excluded.value,
        }
        self.events.publish("spc", self.snapshot())
        return fields, up

    async def feed_cycle(
        self, cycle_id: int, measured: MeasuredDeviation | None, *, recipe: str | None, calibration_read: Mapping[str, Any],
        applied: dict[str, float], failed: bool = False,
    ) -> tuple[dict[str, Any], SpcUpdate | None]:
        """A finished cycle's measured result into its recipe's loop (a failed cycle counts as not installed):
        the record's ``spc`` fields. A fault of the loop must not cost the cycle its record: logged, and said there."""
        if failed and "version" not in calibration_read:
            # Failed before it read the calibration set: no version to file it under (feeding it
            # under none would read as a new set and reset the loop).
            return {"skipped": "the cycle ended before it read the calibration set"}, None
        try:
            assert recipe is not None  # set with the calibration's reference
            return await self.after_cycle(
                cycle_id, None if measured is None else measured.deviation, recipe=recipe,
                calibration=calibration_key(calibration_read), applied=applied,
                reliable=measured is None or measured.reliable,
            )  # fmt: skip
        except Exception as err:  # noqa: BLE001 - logged with its trace; the record and the cell go on
            log.exception("cycle %d: the closed loop could not take its result", cycle_id)
            return {"error": f"{type(err).__name__}: {err}"}, None

    async def raise_drift(self, cycle_id: int, up: SpcUpdate, recipe: str) -> None:
        """Alarm 1313 for a drift of ``recipe``'s loop that started with this cycle (the loop holds that axis's
        estimate and offset until a reset: :class:`cellctl.quality.SpcLoop`)."""
        if not up.drift_started:
            return
        what = ", ".join(_drift_text(d, up.state.offset[d.axis]) for d in up.drift_started)
        await self.alarms.raise_alarm(
            AlarmCode.SPC_DRIFT, source="spc", cycle_id=cycle_id,
            detail=f"{recipe}'s install offset drifts: {what}; the loop stops following it. Run `cellctl calibrate "
            "verify`, recalibrate what it names, then the new calibration of this recipe's parts resets its loop",
        )  # fmt: skip

    async def reset(self, *, actor: str, source: str, recipe: str | None = None) -> None:
        """An operator's reset of ``recipe``'s loop (None: every recipe's): forget the estimate and any
        drift (after a repair that needs no recalibration)."""
        before: dict[str, dict[str, float]] = {}
        for name in self.recipes if recipe is None else [recipe]:
            self.known(name)
            up = self.loop.reset(self.states[name], at=datetime.now(timezone.utc))
            if up.record is not None:
                await self.store.save_spc(state_to_dict(up.state), up.record.as_entry(), recipe=name)
            self.states[name] = up.state
            before[name] = dict(up.previous_offset)
        await self.store.append_audit(
            actor=actor, source=source, action="spc.reset", params={"offset_before": before}  # by recipe
        )
        self.events.publish("spc", self.snapshot())

    def snapshot(self) -> dict[str, Any]:
        """The loops for /status and the dashboard: the first recipe's at the top level (as when the cell had
        one loop), every recipe's under ``recipes`` in the configuration's order."""
        views = [self.view(name) for name in self.recipes]
        return {**views[0], "recipes": views}

    def view(self, recipe: str) -> dict[str, Any]:
        """One recipe's loop: on or off, estimate, offset, samples, drift."""
        s = self.states[recipe]
        return {
            "recipe": recipe,
            "enabled": self.config.enabled,
            "calibration_version": s.calibration_version,
            "samples": s.n_samples,
            "min_samples": self.config.min_samples,
            "estimate": {a: _figure(self.loop.working_estimate(x)) for a, x in s.axes.items()},
            "offset": {k: float(v) for k, v in s.offset.items()} if self.config.enabled else None,
            "excluded": dict(s.excluded),
            "drifting": [{"axis": d.axis, "kind": d.kind.value, "value": d.value, "limit": d.limit, "gate": d.gate,
                          "tested": d.tested} for d in s.drifting],  # fmt: skip
            "limits": {
                "max_offset_mm": self.config.max_offset_mm, "max_offset_deg": self.config.max_offset_deg,
                "drift_limit_mm": self.config.drift_limit_mm, "drift_limit_deg": self.config.drift_limit_deg,
            },
            "updated_at": None if s.updated_at is None else s.updated_at.isoformat(),
        }


def calibration_key(reference: Mapping[str, Any]) -> str:
    """What a recipe's loop is learnt under, from a calibration source's reference for that recipe: the
    ids of the parts its cycles use (``parts-`` and 12 hex digits of their digest), so a new version of the
    set that changes none of them (another recipe taught) keeps the loop; without part ids, the set's
    version ("none": the oracle has none)."""
    parts = reference.get("parts")
    if isinstance(parts, Mapping) and parts:
        ids = "\n".join(f"{name}={parts[name]}" for name in sorted(parts))
        return "parts-" + hashlib.sha256(ids.encode("utf-8")).hexdigest()[:12]
    v = reference.get("version")
    return "none" if v is None else str(v)


def _figure(v: float | None) -> float | None:
    return None if v is None else float(v)


def _drift_text(d: Drift, held: float) -> str:
    """One drift for alarm 1313: a trend against the drift limit, a step against the gate its results failed, and
    the offset the axis holds from now on (axis unit)."""
    unit = axis_unit(d.axis)
    if d.kind is DriftKind.STEP and d.gate is not None:
        tested = d.value if d.tested is None else d.tested  # (a drift stored before it was recorded: the deviation)
        seen = f"step of {tested:+.3f} {unit} (gate +-{d.gate:.3g} {unit})"
    else:
        seen = f"{d.kind.value} {d.value:+.3f} (limit {d.limit:g})"
    return f"{d.axis} {seen}, offset held at {held:+.3f} {unit}"
