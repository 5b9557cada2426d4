"""The measured install deviation: the six figures of the glass against the opening, from the inspection.

In-plane (dX, dY, dRz) come from the gaps in the image, out-of-plane (dZ, dRx, dRy) from the
flush; both relative to the opening itself, never through the robot's calibration chain. They
are the paper's six figures (section 5.3) in the workpiece frame T, as the twin scores its truth.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from cellctl.domain import InstallDeviation
from cellctl.inspection.flush import FlushResult


@dataclass(frozen=True)
class MeasuredDeviation:
    """What the inspection measured of one installed glass.

    Attributes:
        deviation: the six figures (mm, deg) in the workpiece frame T.
        top_gap_mm, right_gap_mm: the gaps between the glass's and the opening's edges at the corner.
        flush: the laser's flush result.
    """

    deviation: InstallDeviation
    top_gap_mm: float
    right_gap_mm: float
    flush: FlushResult

    def as_dict(self) -> dict[str, float]:
        """The six figures by name (as the twin's truth is recorded)."""
        return asdict(self.deviation)

    def outside(self, position_mm: float, orientation_deg: float) -> list[str]:
        """The figures outside +-tolerance, as readable ``name=value`` items (empty when the part is OK)."""
        d = self.deviation
        # not (|v| <= tol): a NaN or infinite figure is outside too
        out = [f"{k}={v:+.3f}" for k, v in (("dx_mm", d.dx_mm), ("dy_mm", d.dy_mm), ("dz_mm", d.dz_mm)) if not abs(v) <= position_mm]
        out += [
            f"{k}={v:+.3f}"
            for k, v in (("drx_deg", d.drx_deg), ("dry_deg", d.dry_deg), ("drz_deg", d.drz_deg))
            if not abs(v) <= orientation_deg
        ]
        return out

    @property
    def reliable(self) -> bool:
        """False when the flush marked itself unreliable (a tilt-setting spot missing or left out)."""
        return self.flush.unreliable is None


def measured_deviation(
    dx_mm: float, dy_mm: float, drz_rad: float, flush: FlushResult, *, top_gap_mm: float, right_gap_mm: float
) -> MeasuredDeviation:
    """Combine the image's in-plane figures with the laser's flush into the six figures."""
    return MeasuredDeviation(
        InstallDeviation(
            dx_mm=float(dx_mm),
            dy_mm=float(dy_mm),
            dz_mm=flush.dz_mm,
            drx_deg=float(np.degrees(flush.drx_rad)),
            dry_deg=float(np.degrees(flush.dry_rad)),
            drz_deg=float(np.degrees(drz_rad)),
        ),
        float(top_gap_mm),
        float(right_gap_mm),
        flush,
    )
