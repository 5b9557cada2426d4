"""The inspection step on an arc corner (issue 21): the gaps on the arc and its top edge, the flush.

After the release and back-off: the shooting pose of T2, one image, the opening's and the glass's
arcs (cellctl.vision.arc_gap), the flush as for any recipe; the six figures from both.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any

from cellctl.cell.cycle_failure import CycleFailed
from cellctl.cell.inspect_figures import inspection_image, record_measured
from cellctl.domain import AlarmCode, CycleStep
from cellctl.geometry.pose import Pose
from cellctl.inspection import FlushResult, MeasuredDeviation
from cellctl.vision.annotate_arc import annotate_arc
from cellctl.vision.arc_gap import ArcGapMeasurement, in_plane_from_arcs, measure_arc_gaps
from cellctl.vision.gap import SUBPIXEL_SEARCH_PX

if TYPE_CHECKING:
    from cellctl.cell.cycle import CycleRun

STEP = CycleStep.INSPECT
_GLASS_SEARCH_MM = 2.0  # the glass's arc is sought this far about the nominal gap


async def _record(run: CycleRun, image: Any, m: ArcGapMeasurement, figures: dict[str, Any] | None) -> None:
    """The inspection image: the glass's arc where found (else the opening's), as the cycle's ``inspect`` image."""
    shown = m.glass if m.glass is not None else m.opening
    png = await asyncio.to_thread(annotate_arc, image, shown, run.cal.lens, run.vision.roi, taught=run.cal.template)
    await run.rec.image("inspect", png)
    if figures is not None:
        await run.rec.step_figures(STEP, {"arc_gaps": figures})


async def inspect_arc_corner(
    run: CycleRun, T2: Pose, measure_flush: Callable[[CycleRun, Pose], Awaitable[tuple[FlushResult, dict[str, Any]]]]
) -> MeasuredDeviation:
    """The shooting pose of T2, the arcs' image, the flush: the installed glass's six figures."""
    cal, arc = run.cal, run.feature.arc
    assert arc is not None
    image = await inspection_image(run, T2)
    mm_per_px = cal.nine_point.mm_per_px
    gap_px = run.process.inspect.nominal_gap_mm / mm_per_px
    m = await asyncio.to_thread(
        measure_arc_gaps, image, cal.lens, arc, gap_px_expected=gap_px, search_px=max(_GLASS_SEARCH_MM / mm_per_px, SUBPIXEL_SEARCH_PX)
    )  # fmt: skip
    if not m.ok:
        await _record(run, image, m, None)
        raise CycleFailed(STEP, AlarmCode.INSPECTION_FAILED, f"the gaps on the arc could not be measured: {m.message}")
    flush, flush_figures = await measure_flush(run, T2)
    radius_mm = -run.feature.point_mm[0]  # the arc's centre lies at (-R, R) in T
    plane = in_plane_from_arcs(
        m, cal.nine_point, cal.lens, radius_mm=radius_mm, dz_mm=flush.dz_mm, drx_rad=flush.drx_rad, dry_rad=flush.dry_rad,
        working_distance_mm=run.process.working_distance_mm,
    )  # each glass point at its depth on the flush's glass plane (a tilted glass's arc spans 100-300 mm)
    await _record(run, image, m, plane.as_dict())
    return await record_measured(run, plane, flush, flush_figures, arc=True)
