"""The profile teaching saw across each straight edge, and the feature found again by it on a shot.

The recipe's rule (:class:`cellctl.config.vision.FeatureConfig`) counts steps: a car body showing
an extra parallel edge of the opening's polarity (a paint line, a painted flange border a few mm
outside the wall's edge) or lacking one that teaching saw makes it count another edge, and the
corner is measured there, precisely and wrongly. So teaching records the template's profile per
edge (every step's place from the feature step, px into the opening at the fixed shooting scale,
its change and size: :class:`TaughtEdge`), and a shot's feature is the one step whose
neighbourhood shows the taught pattern (:func:`match_taught`). Steps of the opening's polarity are
compared, on either profile, when they are

- strong: as large as the rule counts (``min_step_fraction``) and at least 1/``SIZE_RATIO`` of the
  feature's size, anywhere both profiles cover on the side the rule counts from (a step beyond the
  feature changes no count, and a band there, a flange or a seal, varies in width from body to body); or
- near: within ``taught_near_px`` of the feature and at least ``min_step_fraction / SIZE_RATIO``
  (an edge a few mm beside the feature that took part of its contrast);

and each needs a counterpart on the other profile within ``taught_place_px``, of the same
polarity and a size within a factor of ``SIZE_RATIO``. No step, or more than one, matching is a
refusal naming what differs. Fainter and farther steps are left out: they never change what the
rule counts, and they vary from body to body (a paint band's width, a flange's or a seal's grey).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from cellctl.config.vision import FeatureConfig
from cellctl.vision.profile import EdgeProfile, ProfileStep

SIZE_RATIO = 2.0  # a counterpart's size (share of the range) within this factor of the step's
END_MARGIN_PX = 8.0  # steps this near either end of a profile may be cut by it: not compared

__all__ = ["SIZE_RATIO", "TaughtEdge", "TaughtProfile", "TaughtRule", "match_taught", "rule_problem", "taught_edge"]


@dataclass(frozen=True)
class TaughtRule:
    """The recipe's feature rule when taught (``[vision.feature]`` count_from, index, min_step_fraction)."""

    count_from: str
    index: int
    min_step_fraction: float

    @classmethod
    def of(cls, feature: FeatureConfig) -> "TaughtRule":
        return cls(feature.count_from, feature.index, float(feature.min_step_fraction))

    def same_as(self, feature: FeatureConfig) -> bool:
        return (self.count_from, self.index) == (feature.count_from, feature.index) and abs(
            self.min_step_fraction - feature.min_step_fraction
        ) < 1e-9


@dataclass(frozen=True)
class TaughtEdge:
    """The template's profile across one edge: its steps with ``offset_px`` from the feature step
    (px, positive into the opening; the feature's own is 0), and the stretch the profile covered
    (``seen_px``: first and last sample with a level, from the feature step)."""

    steps: tuple[ProfileStep, ...]
    feature: int
    seen_px: tuple[float, float]

    @property
    def feature_step(self) -> ProfileStep:
        return self.steps[self.feature]


@dataclass(frozen=True)
class TaughtProfile:
    """What teaching saw across the template's straight edges (by edge name) and the rule it picked with."""

    rule: TaughtRule
    edges: dict[str, TaughtEdge]


def _seen(profile: EdgeProfile) -> tuple[float, float]:
    ok = profile.offsets_px[profile.levels_dn == profile.levels_dn]  # finite levels (NaN != NaN)
    return (float(ok[0]), float(ok[-1])) if len(ok) else (0.0, 0.0)


def taught_edge(profile: EdgeProfile) -> TaughtEdge | None:
    """The template's profile of one edge as teaching records it (None: no feature on it)."""
    step = profile.feature_step
    if step is None or profile.feature is None:
        return None
    at = step.offset_px
    steps = tuple(ProfileStep(s.offset_px - at, s.change_dn, s.fraction) for s in profile.steps)
    lo, hi = _seen(profile)
    return TaughtEdge(steps, profile.feature, (lo - at, hi - at))


def _words(s: ProfileStep, at: float = 0.0) -> str:
    return f"{s.offset_px - at:+.0f} px {s.change_dn:+.0f} DN ({s.fraction:.2f})"


def _alike(a: ProfileStep, b: ProfileStep, tol_px: float) -> bool:
    small, large = sorted((a.fraction, b.fraction))
    return (a.change_dn < 0) == (b.change_dn < 0) and abs(a.offset_px - b.offset_px) <= tol_px and large <= SIZE_RATIO * small


def _differences(
    steps: tuple[ProfileStep, ...], k: int, window: tuple[float, float], taught: TaughtEdge, dark: bool,
    feature: FeatureConfig,
) -> list[str]:
    """What the neighbourhood of ``steps[k]`` shows unlike the taught one (empty: it matches)."""
    at = steps[k].offset_px
    seen = [ProfileStep(s.offset_px - at, s.change_dn, s.fraction) for s in steps]
    lo, hi = window
    tol, near = float(feature.taught_place_px), float(feature.taught_near_px)
    strong = max(feature.min_step_fraction, steps[k].fraction / SIZE_RATIO)

    def compared(s: ProfileStep) -> bool:
        if not (lo <= s.offset_px <= hi and (s.change_dn < 0) == dark) or s.offset_px == 0.0:
            return False
        counted = s.offset_px < 0.0 if feature.count_from == "wall" else s.offset_px > 0.0  # between the start and it
        faint = feature.min_step_fraction / SIZE_RATIO
        return (counted and s.fraction >= strong) or (abs(s.offset_px) <= near and s.fraction >= faint)

    out = [f"a step at {_words(s)} that teaching did not see" for s in seen
           if compared(s) and not any(_alike(s, t, tol) for t in taught.steps)]  # fmt: skip
    out += [f"no step where teaching saw one at {_words(t)}" for t in taught.steps
            if compared(t) and not any(_alike(t, s, tol) for s in seen)]  # fmt: skip
    return out


def match_taught(
    profile: EdgeProfile,
    taught: TaughtEdge,
    opening_darker: bool,
    feature: FeatureConfig,
    *,
    below_px: float | None = None,
) -> tuple[int | None, str]:
    """Index in ``profile.steps`` of the one step whose neighbourhood matches the taught one, or None and why.

    Steps are compared where both profiles have levels (less ``END_MARGIN_PX`` at each end) and,
    with ``below_px``, only those lying below that offset on ``profile`` (px from its line into the
    opening: the inspection leaves out the glass's side).
    """
    seen = _seen(profile)
    like = taught.feature_step
    candidates = [k for k, s in enumerate(profile.steps) if _alike(s, replace(like, offset_px=s.offset_px), 0.0)]
    matches: list[int] = []
    report: dict[int, list[str]] = {}
    for k in candidates:
        at = profile.steps[k].offset_px
        lo = max(seen[0] - at, taught.seen_px[0]) + END_MARGIN_PX
        hi = min(seen[1] - at, taught.seen_px[1]) - END_MARGIN_PX
        if below_px is not None:
            hi = min(hi, below_px - at)
        report[k] = _differences(profile.steps, k, (lo, hi), taught, opening_darker, feature)
        if not report[k]:
            matches.append(k)
    if len(matches) == 1:
        return matches[0], ""
    shown = ", ".join(_words(s) for s in taught.steps) or "none"
    found = ", ".join(_words(s) for s in profile.steps) or "none"
    if matches:
        where = " and ".join(f"{profile.steps[k].offset_px:+.0f} px" for k in matches)
        why = f"{len(matches)} steps ({where}) match the taught profile equally"
    elif not candidates:
        why = f"no step of the taught feature's polarity and size ({_words(taught.feature_step)})"
    else:
        k = min(candidates, key=lambda c: len(report[c]))
        why = f"the likeliest feature ({_words(profile.steps[k])} from the line) has {'; '.join(report[k])}"
    return None, (
        f"the profile differs from the one taught: {why} (taught steps from the feature: {shown}; steps now, from the "
        f"line: {found}). If the car body or its paint changed, teach the recipe again; if the edge is to be found "
        "otherwise, set [vision.feature] (taught_place_px, taught_near_px, or taught_profile = false to count by the rule alone)"
    )


def rule_problem(taught: TaughtProfile, feature: FeatureConfig) -> str | None:
    """Why the taught profile cannot check the recipe's rule now (None: taught with this rule)."""
    if taught.rule.same_as(feature):
        return None
    r = taught.rule
    return (
        f"[vision.feature] changed since teaching (taught: step {r.index} from the {r.count_from}, at least "
        f"{r.min_step_fraction:g} of the range; now: step {feature.index} from the {feature.count_from}, at least "
        f"{feature.min_step_fraction:g}): the template is on another edge; set it back, or teach the recipe again"
    )
