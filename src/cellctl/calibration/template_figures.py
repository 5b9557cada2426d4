"""What teaching records of its template image besides the feature: the corner's angle, and the
recipe's feature rule with the steps the template's profiles showed (for the commissioning report)."""

from __future__ import annotations

from typing import Any

import numpy as np

from cellctl.config.schema import CellConfig
from cellctl.vision.arc_corner import ArcCornerMeasurement
from cellctl.vision.corner import CornerMeasurement


def corner_angle_deg(m: CornerMeasurement | ArcCornerMeasurement) -> float | None:
    angle = getattr(m, "corner_angle_rad", None)  # the arc's corner is square by its fit
    return None if angle is None else float(np.degrees(angle))


def taught_feature(m: CornerMeasurement | ArcCornerMeasurement, config: CellConfig) -> dict[str, Any]:
    """The recipe's feature rule and, per edge, the steps the template's profile shows and the one it picked."""
    feature = config.vision.feature
    out: dict[str, Any] = {"rule": feature.model_dump()}
    if isinstance(m, ArcCornerMeasurement):
        return out | {"arc": {"radius_px": m.radius_px, "coverage_deg": m.coverage_deg}}
    for edge in (m.top, m.right):
        prof = edge.profile if edge is not None else None
        if prof is None:
            continue
        out[edge.name] = {
            "steps": [{"offset_px": st.offset_px, "change_dn": st.change_dn, "fraction": st.fraction} for st in prof.steps],
            "feature": prof.feature,
        }
    return out
