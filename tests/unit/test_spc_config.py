"""[process.spc]: defaults, the bounds of each field, and the cross-field rules that name the fix."""

from __future__ import annotations

import tomllib

import pytest
from pydantic import ValidationError

from cellctl.config.spc import SpcConfig


def test_the_defaults() -> None:
    c = SpcConfig()
    assert (c.enabled, c.ewma_lambda, c.min_samples) == (True, 0.1, 5)
    assert (c.dead_band_mm, c.max_offset_mm, c.drift_limit_mm) == (0.02, 0.2, 0.25)
    assert (c.dead_band_deg, c.max_offset_deg, c.drift_limit_deg) == (0.005, 0.05, 0.08)
    assert (c.outlier_k, c.outlier_run) == (4.0, 3)


def test_a_toml_section_loads() -> None:
    doc = tomllib.loads("[process.spc]\newma_lambda = 1.0\nmin_samples = 10\nmax_offset_deg = 0.06\n")
    c = SpcConfig(**doc["process"]["spc"])
    assert (c.ewma_lambda, c.min_samples, c.max_offset_deg) == (1.0, 10, 0.06)


@pytest.mark.parametrize(
    ("fields", "match"),
    [
        ({"ewma_lambda": 0.0}, "ewma_lambda"),
        ({"ewma_lambda": 1.5}, "ewma_lambda"),
        ({"max_offset_mm": float("inf")}, "finite"),
        ({"min_samples": 2}, "min_samples"),
        ({"max_offset_mm": 0.0}, "max_offset_mm"),
        ({"dead_band_deg": -0.001}, "dead_band_deg"),
        ({"outlier_k": 1.0}, "outlier_k"),
        ({"outlier_run": 1}, "outlier_run"),
        ({"sigma_floor_mm": 0.0}, "sigma_floor_mm"),
        ({"gain": 0.5}, "gain"),  # a typo is refused, not ignored
        ({"dead_band_mm": 0.2}, r"dead_band_mm = 0.2 is not below max_offset_mm = 0.2.*lower dead_band_mm"),
        ({"drift_limit_deg": 0.05}, r"drift_limit_deg = 0.05 does not exceed max_offset_deg = 0.05.*raise drift_limit_deg"),
        ({"max_offset_mm": 0.3}, r"drift_limit_mm = 0.25 does not exceed max_offset_mm = 0.3"),
    ],
)
def test_bad_settings_are_refused_naming_the_field_and_the_fix(fields: dict[str, object], match: str) -> None:
    with pytest.raises(ValidationError, match=match):
        SpcConfig(**fields)  # type: ignore[arg-type]
