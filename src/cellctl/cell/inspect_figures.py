"""The inspection's six figures from the image's in-plane part and the laser's flush, recorded."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from cellctl.domain import CycleStep
from cellctl.inspection import FlushResult, MeasuredDeviation, measured_deviation
from cellctl.vision.gap_figures import InPlaneGaps

if TYPE_CHECKING:
    from cellctl.cell.cycle import CycleRun


async def record_measured(
    run: CycleRun, plane: InPlaneGaps, flush: FlushResult, flush_figures: dict[str, Any], *, arc: bool = False
) -> MeasuredDeviation:
    """The measured deviation, recorded with the gaps (the second one across the arc for an arc corner) and the flush's figures."""
    measured = measured_deviation(
        plane.dx_mm, plane.dy_mm, plane.drz_rad, flush, top_gap_mm=plane.top_gap_mm, right_gap_mm=plane.right_gap_mm
    )
    await run.rec.step_figures(
        CycleStep.INSPECT,
        {
            "measured_deviation": measured.as_dict(),
            "top_gap_mm": plane.top_gap_mm,
            "arc_gap_mm" if arc else "right_gap_mm": plane.right_gap_mm,
            **flush_figures,
            "flush_fit_rms_mm": {"glass": flush.glass_rms_mm, "wall": flush.wall_rms_mm},
            "dz_sigma_mm": flush.dz_sigma_mm,
        },
    )
    return measured
