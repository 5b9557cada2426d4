"""What a real car-body opening looks like around its edge, for the twin's camera.

A real opening is not a clean step from the painted wall to the dark interior. Across the edge,
from the wall inwards, the twin can draw:

- a **paint band** on the wall just outside the edge (a primer strip or a masked stripe): its
  outer border is a paint edge, a weak step parallel to the opening's edge;
- the **wall's edge** itself (the feature the default recipe teaches: the install target's edge);
- a **flange**: the bonding flange, recessed, seen as a mid-grey band inside the edge;
- a **seal**: the dark rubber seal beyond the flange, whose inner border is the last, weak step
  to the car interior.

Each band is drawn along the whole opening, its border a rounded rectangle offset from the
opening's (an inner offset's corner radius shrinks by its depth). Across a straight edge near the
corner the twin can also lay **marks** (tape, a label's edge, a pen line, a weld seam: thin bright
or dark strips at any angle) and spots of **dirt**.

Widths, greys, angles and positions are drawn from the ranges below once per car body (a seed
derived from its placement), so every frame of one car body shows the same surface. A range is
``[low, high]``; give the same value twice for a fixed one. Greys are DN above the black level at
the image centre, like ``wall_dn`` and ``opening_dn``.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import AfterValidator, Field, field_validator

from cellctl.config.types import Finite, StrictModel


def _low_high(v: tuple[float, float]) -> tuple[float, float]:
    if v[0] > v[1] or v[0] < 0:
        raise ValueError(f"must be [low, high] with 0 <= low <= high, got [{v[0]:g}, {v[1]:g}]; swap them or raise low to 0")
    return v


def _count_up_to(top: int) -> AfterValidator:
    def check(v: tuple[int, int]) -> tuple[int, int]:
        if v[0] < 0 or v[1] > top or v[0] > v[1]:
            raise ValueError(f"count must be [low, high] with 0 <= low <= high <= {top}, got {list(v)}")
        return v

    return AfterValidator(check)


Range = Annotated[tuple[Finite, Finite], AfterValidator(_low_high)]
"""[low, high], both at least 0 (drawn uniformly per car body)."""


class BandConfig(StrictModel):
    """A band along the opening's edge: how wide it is (mm, across the edge) and its grey (DN)."""

    width_mm: Range
    dn: Range

    @field_validator("width_mm")
    @classmethod
    def _width(cls, v: tuple[float, float]) -> tuple[float, float]:
        if v[0] <= 0 or v[1] > 60:
            raise ValueError(f"width_mm must lie in (0, 60] mm, got [{v[0]:g}, {v[1]:g}]")
        return v

    @field_validator("dn")
    @classmethod
    def _dn(cls, v: tuple[float, float]) -> tuple[float, float]:
        if v[0] < 0 or v[1] > 255:
            raise ValueError(f"dn must lie in [0, 255], got [{v[0]:g}, {v[1]:g}]")
        return v


class MarksConfig(StrictModel):
    """Thin strips crossing a straight edge near the corner (tape, a pen line, a weld seam).

    Each mark crosses the top or the right edge (drawn at random) at ``within_mm`` or less from
    the virtual corner along that edge, at ``angle_deg`` to it (90 is square across), centred on
    the crossing. ``kind`` "either" draws bright or dark per mark.
    """

    count: Annotated[tuple[int, int], _count_up_to(20)] = (1, 2)
    within_mm: Finite = Field(30.0, gt=0, le=500)
    width_mm: Range = (0.3, 1.5)
    length_mm: Range = (15.0, 60.0)
    angle_deg: Range = (15.0, 165.0)
    kind: Literal["bright", "dark", "either"] = "either"
    bright_dn: Range = (190.0, 235.0)
    dark_dn: Range = (5.0, 40.0)


class DirtConfig(StrictModel):
    """Round spots (dust, sealant drops, dried water) near the corner, on the wall and the bands.

    Spot centres are drawn uniformly within ``within_mm`` of the virtual corner along both
    straight edges and up to ``spread_mm`` off them.
    """

    count: Annotated[tuple[int, int], _count_up_to(200)] = (3, 10)
    within_mm: Finite = Field(80.0, gt=0, le=1000)
    spread_mm: Finite = Field(12.0, ge=0, le=200)
    radius_mm: Range = (0.15, 0.8)
    dn: Range = (10.0, 90.0)


class SurfaceConfig(StrictModel):
    """The car body's surface around the opening (see the module docstring).

    A part set to None (``false`` in TOML, which has no null) is not drawn; one left out of a TOML
    file takes its default. The defaults are a realistic train-body opening: a primer strip
    outside the edge, a bonding flange and a rubber seal inside it; no marks or dirt.
    """

    paint_band: BandConfig | None = BandConfig(width_mm=(8.0, 15.0), dn=(128.0, 142.0))
    flange: BandConfig | None = BandConfig(width_mm=(4.0, 7.0), dn=(45.0, 65.0))
    seal: BandConfig | None = BandConfig(width_mm=(6.0, 10.0), dn=(28.0, 38.0))
    marks: MarksConfig | None = None
    dirt: DirtConfig | None = None

    @field_validator("paint_band", "flange", "seal", "marks", "dirt", mode="before")
    @classmethod
    def _off(cls, v: object) -> object:
        return None if v is False else v


CLEAN_SURFACE = SurfaceConfig(paint_band=None, flange=None, seal=None)
"""A clean step from the wall to the interior (what the twin drew before real openings)."""
