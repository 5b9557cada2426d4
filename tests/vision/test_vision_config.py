"""VisionConfig: defaults valid, bad settings refused with the field named."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from cellctl.config.vision import CoarseConfig, RoiConfig, VisionConfig


def test_defaults_are_valid_and_fit_the_paper_camera() -> None:
    cfg = VisionConfig()
    cfg.roi.check_inside(2048, 2048)
    assert cfg.fit.arc_exclusion_px > 30.0 / (400.0 / 5249.574)  # beyond the 30 mm corner radius
    assert cfg.opening_polarity == "darker"


def test_bad_settings_are_refused_naming_the_field() -> None:
    with pytest.raises(ValidationError, match="canny_low"):
        CoarseConfig(canny_low=80.0, canny_high=50.0)
    with pytest.raises(ValidationError, match="downscale"):
        CoarseConfig(downscale=3)
    with pytest.raises(ValidationError, match="extra"):
        VisionConfig.model_validate({"roi": {"x_px": 0, "wdth_px": 100}})
    with pytest.raises(ValidationError, match="opening_polarity"):
        VisionConfig(opening_polarity="dark")
    with pytest.raises(ValidationError, match="limits.max_fit_rms_px"):
        VisionConfig.model_validate({"limits": {"max_fit_rms_px": float("nan")}})


def test_roi_outside_the_image_names_the_fix() -> None:
    roi = RoiConfig(x_px=1500, y_px=0, width_px=1000, height_px=500)
    with pytest.raises(ValueError, match="x_px \\+ width_px = 2500 exceeds the image width 2048"):
        roi.check_inside(2048, 2048)
    RoiConfig(x_px=1000, y_px=1000, width_px=1048, height_px=1048).check_inside(2048, 2048)
