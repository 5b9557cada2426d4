"""Whether a calibration set lets a recipe go into production: every part present, ok, in date, taught for it and
computed from the parts the set holds now; one line per problem, each naming the command that mends it.

A part is in date until :func:`expires_utc`: its calibration time plus the shorter of the validity recorded with it
(``valid_days``, the ``calibration.max_age_days`` in force when it was calibrated) and the running configuration's
``calibration.max_age_days`` (lowering the limit applies at once; raising it, to parts calibrated after).

A part dated ahead of the cell's clock (calibrated while the clock was ahead; NTP has stepped it back since) counts its
age from the earlier of its date and now, so it is used, with a warning, and still expires on :func:`expires_utc`; one
dated more than its validity ahead is refused as calibrated in the future."""

from __future__ import annotations

import logging
import os
import shlex
from datetime import datetime, timedelta, timezone
from pathlib import Path

from cellctl.calibration.calibration_set import (
    COMMANDS,
    DEPENDS_ON,
    PART_NAMES,
    RECIPE_PART_NAMES,
    CalibrationSet,
    RecipeParts,
    command,
    parts_of,
    recipe_named,
    taught_for,
    wall_read_problem,
)
from cellctl.calibration.dataset import dataset_folder
from cellctl.calibration.set_parts import PartRecord, TeachingPart
from cellctl.calibration.taught_shot import shot_problem
from cellctl.config import CellConfig

log = logging.getLogger(__name__)

AHEAD_UNSAID = timedelta(minutes=5)
"""A part dated less than this ahead of the cell's clock is not warned about (two hosts' clocks, a slewing NTP)."""
AHEAD_USED = timedelta(days=1)
"""A part dated less than this ahead of the cell's clock is used (NTP stepped back a clock that ran ahead while it was
calibrated); further ahead it is refused: its true age cannot be told, and it would count that much longer."""
_warned: set[tuple[str, str]] = set()  # (part id, label): each logged once per process, not at every status poll


def valid_days(part: PartRecord, config: CellConfig | None = None) -> float:
    """How many days ``part`` counts from its calibration: its recorded ``valid_days``, capped by ``config``'s
    ``calibration.max_age_days`` (no config: the recorded figure alone)."""
    return part.valid_days if config is None else min(part.valid_days, float(config.calibration.max_age_days))


def expires_utc(part: PartRecord, config: CellConfig | None = None) -> datetime | None:
    """When ``part`` stops counting for production (UTC): ``calibrated_utc`` + :func:`valid_days`; None for a failed part.
    (A part dated ahead of the clock, by less than :data:`AHEAD_USED`, ends there too: at most that much late.)"""
    if part.status == "failed":
        return None
    return part.calibrated_utc + timedelta(days=valid_days(part, config))


def check_ready(
    cal: CalibrationSet | None,
    now: datetime,
    *,
    recipe: str | None = None,
    first_recipe: str | None = None,
    config: CellConfig | None = None,
    parts: tuple[str, ...] = PART_NAMES,
    store_root: Path | None = None,
    warnings: list[str] | None = None,
) -> list[str]:
    """Everything that stops production of ``recipe`` (None: the cell's first), one line per problem (empty: ready).

    ``parts`` limits the check to those parts (e.g. ``RECIPE_PART_NAMES``: the recipe's own). A part is a problem
    when it is missing, failed, expired (:func:`expires_utc`, given the cell's ``config``), dated :data:`AHEAD_USED` or
    more in the future (less: a warning, logged once and added to ``warnings`` if given, not a problem), or was
    computed from a part that has since been replaced (stale); a teaching is one when it was
    taught for another recipe than the one it stands for (``first_recipe`` names the cell's first),
    or, given the cell's ``config``, read the wall elsewhere or otherwise than that recipe's cycle does, or was taught
    with other shot settings or for another size of its opening (:func:`cellctl.calibration.taught_shot.shot_problem`).
    ``store_root``: the calibration store folder ``cal`` was read from (the datasets a stale part's hint names are
    found in it: :func:`cellctl.calibration.dataset.dataset_folder`).
    """
    if now.tzinfo is None:
        raise ValueError("now must carry a time zone (use datetime.now(timezone.utc))")
    if cal is None:
        return [f"no calibration set: calibrate and teach the cell first ({', '.join(COMMANDS.values())})"]
    slot = parts_of(cal, recipe, first_recipe)
    wanted = recipe or first_recipe
    # the recipe the fix names: the slot's, or one no longer first read in the first's place (`cellctl teach` is the first's)
    named = recipe_named(slot, wanted, first_recipe)
    problems: list[str] = []
    both = (cal.recipes.get(wanted or "", RecipeParts()).teaching, cal.parts.teaching)
    if wanted is not None and both[0] is not None and taught_for(both[1]) == wanted:  # a set from before one per recipe
        used = cal.part("teaching", slot)
        assert used is not None
        _warn((used.id, f"two of {wanted}"), f"teaching of recipe {wanted}: two teachings, in the first recipe's place and "
              f"under its name (a set written before a recipe kept one); the later dated is used ({_utc(used.calibrated_utc)}"
              f"): if it is not the one taught last, run `{command('teaching', wanted)}`", warnings)  # fmt: skip
    for name in (n for n in PART_NAMES if n in parts):
        p = cal.part(name, slot)
        cmd = command(name, named)
        label = f"{name} of recipe {named}" if name in RECIPE_PART_NAMES and named is not None else name
        if p is None:
            problems.append(f"{label}: missing; run `{cmd}`")
            continue
        if p.status == "failed":
            problems.append(f"{label}: the last calibration failed ({p.failure}); fix the cause and run `{cmd}` again")
            continue
        expires = expires_utc(p, config)
        if expires is not None and now >= expires:
            days = valid_days(p, config)
            by = " by calibration.max_age_days" if days < p.valid_days else ""
            problems.append(
                f"{label}: expired on {expires:%Y-%m-%d %H:%M} UTC (calibrated {p.calibrated_utc:%Y-%m-%d}, "
                f"valid {days:g} days{by}); run `{cmd}`"
            )
        ahead = p.calibrated_utc - now
        if ahead >= AHEAD_USED:
            problems.append(f"{label}: calibrated in the future ({p.calibrated_utc:%Y-%m-%d %H:%M} UTC), "
                            f"{ahead / timedelta(days=1):.1f} days ahead of this cell's clock ({_utc(now)}), a day or more: "
                            f"its age cannot be told; check the clock, or run `{cmd}` again")  # fmt: skip
        elif ahead > AHEAD_UNSAID and expires is not None:
            _warn((p.id, label), f"{label}: calibrated {p.calibrated_utc:%Y-%m-%d %H:%M} UTC, ahead of this cell's clock "
                        f"({_utc(now)}); used, and it expires as dated, on {expires:%Y-%m-%d %H:%M} UTC; check the clock "
                        f"(NTP)", warnings)  # fmt: skip
        owner = taught_for(p)
        if owner is not None and wanted is not None and owner != wanted:
            problems.append(f"{label}: taught for recipe {owner}, not {wanted}; run `{cmd}`")
        elif name == "teaching" and config is not None and isinstance(p, TeachingPart) and p.values is not None:
            of_recipe = wanted or config.default_recipe
            if of_recipe not in {r.name for r in config.process.recipes}:
                problems.append(f"{label}: [[process.recipes]] does not list recipe {of_recipe}; "
                                "add the recipe to the configuration or teach one it lists")
            elif (why := wall_read_problem(p.values.wall_read, config.for_recipe(of_recipe).process.align)) is not None:
                problems.append(f"{label}: {why}; run `{cmd}` again, so the cycle reads the wall where it was taught")
            elif (why := shot_problem(p.values.shot, config.for_recipe(of_recipe), of_recipe)) is not None:
                problems.append(f"{label}: {why} (`{cmd}`, then the parts computed with it)")
        for dep in DEPENDS_ON[name]:
            used = p.inputs.get(dep)
            have = cal.part(dep, slot)
            if used is None:
                problems.append(f"{label}: does not record which {dep} it was computed with; run `{cmd}` again")
            elif have is not None and have.status == "ok" and have.id != used:
                problems.append(f"{label}: computed with {dep} {used}, but the set now holds {dep} {have.id}; run `{cmd}` again"
                                + _offline_way(name, p, store_root))
    return problems


def _utc(when: datetime) -> str:
    return f"{when.astimezone(timezone.utc):%Y-%m-%d %H:%M} UTC"


def _warn(key: tuple[str, str], text: str, into: list[str] | None) -> None:
    """``text`` into ``into`` (if given), and into the log once per ``key`` (part id, label)."""
    if into is not None:
        into.append(text)
    if key not in _warned:
        _warned.add(key)
        log.warning("calibration: %s", text)


def _offline_way(name: str, p: PartRecord, store_root: Path | None) -> str:
    """The other way to redo a stale part: recompute the dataset it was computed from ("": it records none)."""
    if p.dataset is None:
        return ""
    folder = p.dataset.path if store_root is None else os.path.abspath(dataset_folder(p.dataset.path, store_root))
    return (", or, if nothing was touched since its dataset was recorded, recompute that dataset offline once the parts it "
            f"is computed with are current: `{COMMANDS[name]} --dataset {shlex.quote(folder)}`")

