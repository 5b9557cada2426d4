"""Quality loops over measured install results. Pure: no I/O, no clock, no globals; never imports
the cell, the API, the service, the store, a driver or the twin (tests/unit/test_spc_contract.py).

:mod:`cellctl.quality.spc`: the closed-loop offset (an EWMA per axis, bounded, with drift and an
outlier gate); its values and their JSON form are in :mod:`cellctl.quality.spc_state`.
"""

from cellctl.quality.spc import SpcLoop, offset_pose
from cellctl.quality.spc_state import (
    AXES,
    AxisState,
    Drift,
    DriftKind,
    Exclusion,
    SpcEvent,
    SpcRecord,
    SpcState,
    SpcUpdate,
    axis_unit,
    state_from_dict,
    state_to_dict,
)

__all__ = [
    "AXES",
    "AxisState",
    "Drift",
    "DriftKind",
    "Exclusion",
    "SpcEvent",
    "SpcLoop",
    "SpcRecord",
    "SpcState",
    "SpcUpdate",
    "axis_unit",
    "offset_pose",
    "state_from_dict",
    "state_to_dict",
]
