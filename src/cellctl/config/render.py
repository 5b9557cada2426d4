"""How the twin's camera renders images: optics, sensor noise, lighting and disturbances.

The scene (decided for the twin, see cellctl.sim.camera): a painted car body in mid grey, lit by
a ring light beside the camera, so the wall is bright and even; through the window opening the
camera looks into the unlit car interior, which is dark. Levels are grey values (DN, above the
black level) at the image centre; the lighting field (vignetting, gradient) scales them.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from cellctl.config.surface import SurfaceConfig
from cellctl.config.types import Finite, StrictModel


class GlareConfig(StrictModel):
    """A glare spot: stray light from a specular reflection, a Gaussian veil added to the image."""

    peak_dn: Finite = Field(120.0, gt=0, le=1000)  # added grey level at the spot's centre
    sigma_px: Finite = Field(60.0, gt=0, le=2000)  # Gaussian radius of the spot
    on_edge: bool = True  # centre drawn on a visible straight edge of the opening; else anywhere


class OcclusionConfig(StrictModel):
    """Something lying on the wall across part of one straight edge of the opening.

    ``wall_like`` has the wall's brightness (a clamp or a sealing strip), so the edge seems to
    bulge into the opening along that stretch; ``dark`` is a dark strip (a cable, a shadow), so
    the edge seems to bulge into the wall.
    """

    edge: Literal["top", "right", "random"] = "random"
    edge_fraction: Finite = Field(0.3, gt=0, le=1)  # share of the edge's visible straight length
    width_mm: Finite = Field(4.0, gt=0, le=100)  # across the edge, centred on it
    kind: Literal["wall_like", "dark"] = "wall_like"


class DisturbanceConfig(StrictModel):
    """Optional disturbances; each is off by default. Random placements come from the frame's rng."""

    glare: GlareConfig | None = None
    occlusion: OcclusionConfig | None = None
    contrast_factor: Finite = Field(1.0, gt=0, le=1)  # wall-opening contrast scaled about its mean
    defocus_sigma_px: Finite = Field(0.0, ge=0, le=10)  # added to the optics blur in quadrature


class RenderConfig(StrictModel):
    """Image formation of the simulated camera (2048 x 2048, 8-bit mono).

    The sensor defaults describe a CMV4000-class global-shutter sensor (about 13 ke- full well
    read out at 8 bits, so about 50 electrons per grey level).
    """

    blur_sigma_px: Finite = Field(0.8, ge=0, le=10)  # optics point-spread, Gaussian sigma
    read_noise_dn: Finite = Field(1.5, ge=0, le=50)  # sensor read noise, grey levels (one sigma)
    shot_noise: bool = True  # photon (Poisson) noise from electrons_per_dn
    electrons_per_dn: Finite = Field(50.0, gt=0, le=1e6)  # conversion gain
    black_level_dn: Finite = Field(2.0, ge=0, le=64)  # offset added before quantisation
    wall_dn: Finite = Field(150.0, gt=0, le=255)  # painted car body at the image centre
    opening_dn: Finite = Field(20.0, ge=0, le=255)  # dark car interior seen through the opening
    vignetting_power: Finite = Field(4.0, ge=0, le=8)  # illumination falls as cos(field angle)^power
    lighting_gradient: Finite = Field(0.1, ge=0, lt=1)  # relative change across the image width
    lighting_gradient_angle_deg: Finite = Field(30.0, ge=-360, le=360)  # direction, from +u towards +v
    disturbances: DisturbanceConfig = DisturbanceConfig()
    surface: SurfaceConfig = SurfaceConfig()  # seal, flange, paint edge, marks, dirt (cellctl.config.surface)

    @model_validator(mode="after")
    def _levels(self) -> "RenderConfig":
        if self.opening_dn >= self.wall_dn:
            raise ValueError(
                f"opening_dn ({self.opening_dn:g}) must be darker than wall_dn ({self.wall_dn:g}): "
                "the opening shows the unlit car interior against the painted wall"
            )
        # The gradient's largest gain in the image is about 0.71 x lighting_gradient (a corner).
        top = self.wall_dn * (1.0 + 0.75 * self.lighting_gradient) + self.black_level_dn
        if top >= 255.0:
            raise ValueError(
                f"wall_dn ({self.wall_dn:g}) with lighting_gradient ({self.lighting_gradient:g}) and "
                f"black_level_dn ({self.black_level_dn:g}) reaches {top:.0f} DN and saturates the 8-bit "
                "image; lower wall_dn"
            )
        return self
