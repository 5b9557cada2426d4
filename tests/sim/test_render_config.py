"""Render configuration: the defaults load from config/sim.toml, bad values are refused by name."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import pytest
from pydantic import ValidationError

from cellctl.config import ConfigError, load_config, parse_config
from cellctl.config.render import DisturbanceConfig, GlareConfig, OcclusionConfig, RenderConfig

SIM_TOML = Path(__file__).resolve().parents[2] / "config" / "sim.toml"


def _sim_toml() -> dict[str, Any]:
    return tomllib.loads(SIM_TOML.read_text(encoding="utf-8"))


def test_sim_toml_render_section_matches_the_defaults() -> None:
    cfg = load_config(SIM_TOML)
    assert cfg.sim.camera.render == RenderConfig()
    assert cfg.sim.camera.render.disturbances.glare is None


@pytest.mark.parametrize(
    "field, value",
    [
        ("blur_sigma_px", -0.1),
        ("read_noise_dn", float("nan")),
        ("electrons_per_dn", 0.0),
        ("black_level_dn", -1.0),
        ("wall_dn", 300.0),
        ("vignetting_power", -2.0),
        ("lighting_gradient", 1.5),
        ("shot_noise", "sometimes"),
    ],
)
def test_bad_render_values_are_refused_naming_the_field(field: str, value: object) -> None:
    with pytest.raises(ValidationError) as err:
        RenderConfig(**{field: value})
    assert field in str(err.value)


def test_levels_must_contrast_and_fit_in_eight_bits() -> None:
    with pytest.raises(ValidationError, match="opening_dn .* must be darker than wall_dn"):
        RenderConfig(wall_dn=50.0, opening_dn=60.0)
    with pytest.raises(ValidationError, match="saturates the 8-bit image; lower wall_dn"):
        RenderConfig(wall_dn=240.0, lighting_gradient=0.2)


@pytest.mark.parametrize(
    "model, field, value",
    [
        (GlareConfig, "peak_dn", 0.0),
        (GlareConfig, "sigma_px", -5.0),
        (OcclusionConfig, "edge_fraction", 0.0),
        (OcclusionConfig, "edge_fraction", 1.2),
        (OcclusionConfig, "edge", "left"),
        (OcclusionConfig, "kind", "shiny"),
        (OcclusionConfig, "width_mm", 0.0),
        (DisturbanceConfig, "contrast_factor", 0.0),
        (DisturbanceConfig, "contrast_factor", 2.0),
        (DisturbanceConfig, "defocus_sigma_px", -1.0),
    ],
)
def test_bad_disturbance_values_are_refused_naming_the_field(model: type, field: str, value: object) -> None:
    with pytest.raises(ValidationError) as err:
        model(**{field: value})
    assert field in str(err.value)


def test_a_bad_value_in_the_toml_is_reported_with_its_path() -> None:
    data = _sim_toml()
    data["sim"]["camera"]["render"]["disturbances"]["contrast_factor"] = 1.5
    data["sim"]["camera"]["render"]["blur_sigma_px"] = -1.0
    with pytest.raises(ConfigError) as err:
        parse_config(data, "sim.toml")
    text = str(err.value)
    assert "sim.camera.render.disturbances.contrast_factor" in text
    assert "sim.camera.render.blur_sigma_px" in text


def test_an_unknown_render_field_is_refused() -> None:
    data = _sim_toml()
    data["sim"]["camera"]["render"]["blur_sigma"] = 1.0  # misspelt
    with pytest.raises(ConfigError, match=r"sim\.camera\.render\.blur_sigma: unknown field"):
        parse_config(data, "sim.toml")


def test_disturbance_tables_parse_from_toml() -> None:
    data = _sim_toml()
    data["sim"]["camera"]["render"]["disturbances"]["glare"] = {"peak_dn": 90.0}
    data["sim"]["camera"]["render"]["disturbances"]["occlusion"] = {"edge": "top", "kind": "dark"}
    cfg = parse_config(data, "sim.toml").sim.camera.render.disturbances
    assert cfg.glare == GlareConfig(peak_dn=90.0)
    assert cfg.occlusion is not None and cfg.occlusion.edge == "top" and cfg.occlusion.kind == "dark"
