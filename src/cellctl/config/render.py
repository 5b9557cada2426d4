"""How the twin's camera renders images: optics, sensor noise, lighting and disturbances."""

from __future__ import annotations

from pydantic import Field

from cellctl.config.types import Finite, StrictModel


class RenderConfig(StrictModel):
    """Image formation of the simulated camera (2048 x 2048, 8-bit mono)."""

    blur_sigma_px: Finite = Field(0.8, ge=0)  # optics point-spread, Gaussian sigma
    read_noise_dn: Finite = Field(1.5, ge=0)  # sensor read noise, grey levels (one sigma)
