"""The post-install inspection: the gaps in the image, flush by the laser (``[process.inspect]``)."""

from __future__ import annotations

import numpy as np
from pydantic import Field, model_validator

from cellctl.config.types import Finite, StrictModel, Vec2

# A glass spot and its wall spot further apart than this no longer share the robot's accuracy error.
MAX_SPOT_PAIR_MM = 100.0


class FlushSpot(StrictModel):
    """One flush location: a laser spot on the glass and one on the wall beside it.

    Both are (x, y) in the workpiece frame T (x right, y down from the opening's upper-right
    corner; the opening is x < 0, 0 < y). Put the glass spot on the glass (inside the glass edge,
    which lies ``nominal_gap_mm`` inside the opening's edge) and the wall spot on the wall just
    outside the opening, a few tens of mm apart, so that the robot's slowly varying accuracy error
    and the laser's mounting cancel in their difference.
    """

    glass_mm: Vec2
    wall_mm: Vec2

    @model_validator(mode="after")
    def _sides(self) -> "FlushSpot":
        gx, gy = self.glass_mm
        if not (gx < 0.0 and gy > 0.0):
            raise ValueError(
                f"glass_mm {list(self.glass_mm)} is not inside the opening (x < 0 and y > 0 in T); "
                "put the glass spot inside the glass edge"
            )
        apart = float(np.hypot(gx - self.wall_mm[0], gy - self.wall_mm[1]))
        if not 5.0 <= apart <= MAX_SPOT_PAIR_MM:
            raise ValueError(
                f"wall_mm {list(self.wall_mm)} is {apart:.0f} mm from glass_mm {list(self.glass_mm)}; put the wall spot "
                f"just across the opening's edge, 5 to {MAX_SPOT_PAIR_MM:g} mm away, so the robot's and the laser's "
                "slowly varying errors cancel in the difference"
            )
        return self


# Along the top and the right edge from the corner: ten pairs near it average the robot's
# repeatability (one draw per stop) down to what dZ needs; the two far ones fix the tilt.
NEAR_ALONG_MM = (-60.0, -110.0, -160.0, -210.0, -260.0)


def _default_spots() -> tuple[FlushSpot, ...]:
    # In the order the robot visits them: towards the corner along the top, away from it down the side,
    # the far side, the far top (as the sweep on the move, sweep_path_mm).
    near_top = tuple(FlushSpot(glass_mm=(x, 20.0), wall_mm=(x, -15.0)) for x in reversed(NEAR_ALONG_MM))
    near_right = tuple(FlushSpot(glass_mm=(-20.0, -x), wall_mm=(15.0, -x)) for x in NEAR_ALONG_MM)
    far = (
        FlushSpot(glass_mm=(-20.0, 1200.0), wall_mm=(15.0, 1200.0)),
        FlushSpot(glass_mm=(-1700.0, 20.0), wall_mm=(-1700.0, -15.0)),
    )
    return near_top + near_right + far


class InspectionConfig(StrictModel):
    """How the cell measures the glass it installed, relative to the opening (issue 16).

    After the install the gripper releases the glass and the robot backs off to the shooting
    pose. The camera measures the gaps between the glass's edges and the opening's edges at the
    corner (in-plane X, Y, Rz); the laser reads the glass and the wall at each flush spot (Z, Rx,
    Ry). A measured deviation outside ``[process.tolerance]`` marks the part not OK.

    Attributes:
        enabled: run the inspection after every install (off: the record has no measured result).
        nominal_gap_mm: the drawing's gap between the glass's edge and the opening's edge.
        flush_spots: the flush locations; the near ones give Z at the corner, the far ones the tilt.
        min_flush_spots: fewer locations with both readings refuse the measurement.
        reads_per_spot: readings tried at a standing pose before a spot counts as missing (a glass
            returns less light: a reading may come back without a value).
        max_flush_rms_mm: the glass's and the wall's plane fits must leave no larger residual.
        flush_outlier_mm: a flush spot whose step (glass - wall) is off the plane of the other spots' steps by
            more than 4 of its predicted sigmas, and by at least this much, is left out and named (a seal, an
            edge or a reflection under the beam); the floor keeps a near-perfect fit from rejecting noise.
        back_off_mm: the glass is released, then the flange backs away along the wall normal
            this far before it goes to the shooting pose.
    """

    enabled: bool = True
    nominal_gap_mm: Finite = Field(5.0, gt=0, le=30)
    flush_spots: tuple[FlushSpot, ...] = Field(default_factory=_default_spots)
    min_flush_spots: int = Field(8, ge=3)
    reads_per_spot: int = Field(3, ge=1, le=10)
    max_flush_rms_mm: Finite = Field(0.15, gt=0)
    flush_outlier_mm: Finite = Field(0.1, gt=0, le=5.0)
    back_off_mm: Finite = Field(100.0, ge=0)
    # On the move (process.align.mode = "on_the_fly", where the devices can): the laser sweeps these
    # corners in T instead of standing at the flush spots. A leg from the glass (inside its edge) to
    # the wall (outside the opening, past its far sides too: its outline, [layout.opening] or a recipe's own),
    # or back, is a crossing: its readings either side of the edge give the flush there
    # (cellctl.inspection.flush_crossing); readings within sweep_margin_mm of an edge (the gap) are left out.
    # At least three crossings, spread in x and y, each with its middle in the gap (checked against the
    # opening where the cell reads on the move; a recipe with its own opening gives its own path). Default:
    # crossings 200 mm along and 45 mm across an edge of the default 2000 x 1500 mm opening, centred on the
    # default 5 mm gap (y = 2.5, x = -2.5), near and far, in the order that starts beside the corner the camera
    # has just seen (the shooting pose).
    sweep_path_mm: tuple[Vec2, ...] = (
        (-350.0, -20.0), (-150.0, 25.0), (-25.0, 150.0), (20.0, 350.0),
        (20.0, 1100.0), (-25.0, 1300.0), (-1800.0, 25.0), (-1600.0, -20.0),
    )  # fmt: skip
    sweep_margin_mm: Finite = Field(6.0, ge=0, le=50)

    @model_validator(mode="after")
    def _enough(self) -> "InspectionConfig":
        if len(self.flush_spots) < self.min_flush_spots:
            raise ValueError(
                f"flush_spots has {len(self.flush_spots)} locations but min_flush_spots is {self.min_flush_spots}; "
                "add spots or lower min_flush_spots (at least 3: the glass's plane)"
            )
        return self
