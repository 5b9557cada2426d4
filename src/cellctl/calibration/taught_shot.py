"""The settings a teaching's shot stood on, recorded with it and checked against the configuration.

T0 comes from the feature seen at the shooting pose: its kind and place in T (the corner, or the arc's
centre at the corner radius), the camera's working distance and its aim. A change to any of them
after teaching leaves T0, the template and the pixel map describing another shot. g_Pos_0 holds the
glass made for the opening's width and height: another size moves the glass's corner in the gripper.
The opening's nominal place (corner_position_mm) is not recorded: T0 is measured, and the cycle measures
where each car body stands, so a re-measured nominal place needs no new teaching. The template's
edge profiles are recorded too: each shot's feature is found again by them (cellctl.vision.taught_profile).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.set_parts import TaughtProfileValues, TaughtShot
from cellctl.config.feature import feature_kind, shot_aim_mm
from cellctl.config.vision import FeatureConfig
from cellctl.vision.corner import CornerMeasurement
from cellctl.vision.profile import ProfileStep
from cellctl.vision.taught_profile import TaughtEdge, TaughtProfile, TaughtRule, taught_edge

if TYPE_CHECKING:
    from cellctl.config.schema import CellConfig

SAME_MM = 0.01  # settings this near are the same


def _shot(config: CellConfig) -> TaughtShot:
    return TaughtShot(
        working_distance_mm=float(config.process.working_distance_mm),
        feature=feature_kind(config),
        corner_radius_mm=float(config.layout.opening.corner_radius_mm),
        aim_mm=shot_aim_mm(config),
        width_mm=float(config.layout.opening.width_mm),
        height_mm=float(config.layout.opening.height_mm),
    )


def taught_shot(config: CellConfig) -> dict[str, object]:
    """What teaching records of the recipe's shot (``config`` is the recipe's view)."""
    return _shot(config).model_dump(mode="json")


def shot_problem(taught: TaughtShot | None, config: CellConfig, recipe: str) -> str | None:
    """Why the recipe's shot now differs from the taught one (None: as taught, or not recorded)."""
    if taught is None:
        return None
    now = _shot(config)
    changed = []
    if abs(now.working_distance_mm - taught.working_distance_mm) > SAME_MM:
        changed.append(f"process.working_distance_mm was {taught.working_distance_mm:g} mm, now {now.working_distance_mm:g}")
    where = f"([layout.opening], or recipe {recipe}'s [process.recipes.opening])"
    for field in ("corner_radius_mm", "width_mm", "height_mm"):
        was, new = getattr(taught, field), getattr(now, field)
        if was is not None and abs(new - was) > SAME_MM:  # None: taught before it was recorded (not checked)
            changed.append(f"the opening's {field} {where} was {was:g} mm, now {new:g}")
    if now.feature != taught.feature:
        changed.append(f"the shot measured the {taught.feature}, now the {now.feature}")
    if max(abs(a - b) for a, b in zip(now.aim_mm, taught.aim_mm)) > SAME_MM:
        changed.append(
            f"the camera aimed at ({taught.aim_mm[0]:.1f}, {taught.aim_mm[1]:.1f}) mm in T, now at "
            f"({now.aim_mm[0]:.1f}, {now.aim_mm[1]:.1f}) (vision.shot_aim_mm)"
        )
    if not changed:
        return None
    return f"taught with other settings: {'; '.join(changed)}; set them back, or teach the recipe again"


def refuse_changed_shot(manifest: dict[str, Any], config: CellConfig) -> None:
    """Refuse to compute a teaching dataset whose shot stood on other settings than ``config``'s."""
    taken = manifest.get("shot")  # None in a dataset from before it was recorded
    recipe = manifest.get("recipe") or config.default_recipe
    if taken is not None and (why := shot_problem(TaughtShot.model_validate(taken), config, recipe)) is not None:
        raise CalibrationRefused("teaching", "settings_changed", f"the dataset was {why}")


def taught_profile(m: object, feature: FeatureConfig) -> dict[str, object] | None:
    """What teaching records of the template's edge profiles (None: not a corner measurement, or no profile)."""
    if not isinstance(m, CornerMeasurement):
        return None  # the arc's centre: its profile is not checked
    edges = {}
    for edge in (m.top, m.right):
        taught = taught_edge(edge.profile) if edge is not None and edge.profile is not None else None
        if taught is not None:
            steps = [{"offset_px": s.offset_px, "change_dn": s.change_dn, "fraction": s.fraction} for s in taught.steps]
            edges[edge.name] = {"steps": steps, "feature": taught.feature, "seen_px": list(taught.seen_px)}  # type: ignore[union-attr]
    if not edges:
        return None
    rule = {"count_from": feature.count_from, "index": feature.index, "min_step_fraction": feature.min_step_fraction}
    return TaughtProfileValues.model_validate(rule | {"edges": edges}).model_dump(mode="json")


def taught_profile_of(values: TaughtProfileValues | None) -> TaughtProfile | None:
    """The recorded profiles as the corner detector takes them (None: taught before they were recorded)."""
    if values is None:
        return None
    edges = {
        name: TaughtEdge(tuple(ProfileStep(s.offset_px, s.change_dn, s.fraction) for s in e.steps), e.feature, e.seen_px)
        for name, e in values.edges.items()
    }
    return TaughtProfile(TaughtRule(values.count_from, values.index, values.min_step_fraction), edges)
