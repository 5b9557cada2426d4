"""Where the cycle's calibration comes from."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from cellctl.config.calibration_procedure import CalibrationProcedureConfig
from cellctl.config.types import Finite, StrictModel


class CalibrationConfig(StrictModel):
    """``source = "set"``: the versioned calibration set in ``directory`` (the production way).
    ``source = "oracle"``: the simulated cell's true mountings, taught by the paper's procedure
    in the twin (only with mode = "sim"; the error budget's "true calibrations").
    """

    source: Literal["set", "oracle"] = "set"
    directory: str = "var/calibration"
    max_age_days: Finite = Field(90.0, gt=0)  # a part older than this keeps the cell from production
    auto_calibrate_in_sim: bool = True  # the simulated cell calibrates and teaches itself when a part is missing
    procedure: CalibrationProcedureConfig = CalibrationProcedureConfig()  # targets, plans, limits of `cellctl calibrate`
