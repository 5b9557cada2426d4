"""What a teaching's shot stood on, checked against the configuration: each recorded setting, changed alone, is named.

The truth is the change the test makes to the simulated cell's configuration; nothing else differs.
"""

from __future__ import annotations

from calib_test_support import config

from cellctl.calibration.set_parts import TaughtShot
from cellctl.calibration.taught_shot import shot_problem, taught_shot
from cellctl.config.feature import shot_aim_mm
from cellctl.config.schema import CellConfig


def _taught(cfg: CellConfig) -> TaughtShot:
    return TaughtShot.model_validate(taught_shot(cfg))


def _with_opening(cfg: CellConfig, **opening: float) -> CellConfig:
    return cfg.model_copy(update={"layout": cfg.layout.model_copy(update={"opening": cfg.layout.opening.model_copy(update=opening)})})


def test_the_shot_as_taught_has_no_problem() -> None:
    cfg = config()
    assert shot_problem(_taught(cfg), cfg, cfg.default_recipe) is None


def test_a_taller_opening_alone_is_named() -> None:
    # g_Pos_0 holds glass made for the opening's height: another height moves the glass's corner in the gripper.
    cfg = config()
    taller = _with_opening(cfg, height_mm=cfg.layout.opening.height_mm + 20.0)
    problem = shot_problem(_taught(cfg), taller, cfg.default_recipe)
    assert problem is not None and "height_mm" in problem, problem
    assert "width_mm" not in problem and "corner_radius_mm" not in problem


def test_an_aim_moved_along_one_axis_only_is_named() -> None:
    cfg = config()
    x, y = shot_aim_mm(cfg)
    for aim in ((x + 5.0, y), (x, y - 5.0)):
        moved = cfg.model_copy(update={"vision": cfg.vision.model_copy(update={"shot_aim_mm": aim})})
        problem = shot_problem(_taught(cfg), moved, cfg.default_recipe)
        assert problem is not None and "the camera aimed at" in problem, (aim, problem)
