"""Settings of the closed-loop offset from measured install results ([process.spc]).

The loop itself is :mod:`cellctl.quality.spc`: an EWMA estimate per axis of the deviation the cell
would have made without the loop, applied (bounded) to the next installs; an estimate past the
drift limit asks for recalibration instead. Millimetres for x, y, z; degrees for rx, ry, rz.
"""

from __future__ import annotations

from pydantic import Field, model_validator

from cellctl.config.types import Finite, StrictModel


class SpcConfig(StrictModel):
    """The closed loop over measured install deviations ([process.spc]).

    ``enabled = false`` keeps the loop watching (estimate, drift) but applies no offset.
    """

    enabled: bool = True
    ewma_lambda: Finite = Field(0.1, gt=0, le=1)  # weight of the newest result; 1 = the last result alone
    min_samples: int = Field(5, ge=3, le=1000)  # results since the last reset before the estimate (and its gate) starts
    # Before then: the running mean of the results so far is applied from the first result on (Grubbs'
    # harmonic rule: the n-th result moves the setting by 1/n of it), within the dead band and max_offset;
    # false: no offset until min_samples.
    warm_up_offset: bool = True
    dead_band_mm: Finite = Field(0.02, ge=0)  # an estimate within +-this applies no offset
    dead_band_deg: Finite = Field(0.005, ge=0)
    max_offset_mm: Finite = Field(0.2, gt=0)  # the applied offset is clipped to +-this
    max_offset_deg: Finite = Field(0.05, gt=0)
    drift_limit_mm: Finite = Field(0.25, gt=0)  # an estimate past +-this: drift, recalibrate
    drift_limit_deg: Finite = Field(0.08, gt=0)
    outlier_k: Finite = Field(4.0, ge=2, le=20)  # a result further than k robust sigmas from the estimate is excluded
    sigma_floor_mm: Finite = Field(0.01, gt=0)  # the least noise the outlier gate assumes (the measurement's resolution)
    sigma_floor_deg: Finite = Field(0.002, gt=0)
    outlier_run: int = Field(3, ge=2, le=100)  # this many excluded results in a row on one side of one axis: a step

    @model_validator(mode="after")
    def _consistent(self) -> "SpcConfig":
        for unit in ("mm", "deg"):
            dead = getattr(self, f"dead_band_{unit}")
            bound = getattr(self, f"max_offset_{unit}")
            drift = getattr(self, f"drift_limit_{unit}")
            if dead >= bound:
                raise ValueError(
                    f"dead_band_{unit} = {dead:g} is not below max_offset_{unit} = {bound:g}: no offset could ever "
                    f"be applied; lower dead_band_{unit} or raise max_offset_{unit}"
                )
            if drift <= bound:
                raise ValueError(
                    f"drift_limit_{unit} = {drift:g} does not exceed max_offset_{unit} = {bound:g}: the loop would "
                    f"clip its offset without ever asking for recalibration; raise drift_limit_{unit} above "
                    f"max_offset_{unit}"
                )
        return self


def drift_limit_problems(spc: SpcConfig, position_mm: float, orientation_deg: float) -> dict[str, str]:
    """Each drift limit of ``spc`` not below the install tolerance (mm, deg: [process.tolerance]), as
    {field of [process.spc]: why and the fix}; empty when both are below it.

    Results outside the tolerance are rejects, never samples, so the loop's estimate could never reach
    a drift limit at or past it: the drift would go unreported.
    """
    problems = {}
    for unit, what, tol in (("mm", "position_mm", position_mm), ("deg", "orientation_deg", orientation_deg)):
        drift, bound = getattr(spc, f"drift_limit_{unit}"), getattr(spc, f"max_offset_{unit}")
        if not tol > drift:
            also = f" (and process.spc.max_offset_{unit} = {bound:g} below that)" if bound >= tol else ""
            problems[f"drift_limit_{unit}"] = (
                f"{drift:g} is not below the install tolerance process.tolerance.{what} = {tol:g}: results past the "
                f"tolerance are rejects, never samples, so the estimate could never reach the limit; lower "
                f"process.spc.drift_limit_{unit} below {tol:g}{also}, or raise process.tolerance.{what} above {drift:g}"
            )
    return problems
