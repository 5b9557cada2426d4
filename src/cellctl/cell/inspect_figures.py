"""What both inspections share (a corner's and an arc's): the image at T2's shooting pose, and the
six figures from its in-plane part and the laser's flush, recorded."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from cellctl.cell.camera_frame import grab_checked
from cellctl.compensate import shooting_pose_in
from cellctl.domain import CycleStep
from cellctl.geometry.pose import Pose
from cellctl.inspection import FlushResult, MeasuredDeviation, measured_deviation
from cellctl.vision.gap_figures import InPlaneGaps

if TYPE_CHECKING:
    from cellctl.cell.cycle import CycleRun


async def inspection_image(run: CycleRun, T2: Pose) -> np.ndarray:
    """Go to the shooting pose of T2 and grab: the inspection's image."""
    await run.move(CycleStep.INSPECT, shooting_pose_in(run.cal.taught, T2), kind="joint")
    frame = await grab_checked(
        run.dev.camera, run.cal.lens, CycleStep.INSPECT, timeout_s=run.motion.grab_timeout_s, what="no inspection image"
    )
    return frame.image


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
