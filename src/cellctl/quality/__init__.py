"""Quality loops over measured install results. Pure: no I/O, no clock, no globals; never imports
the cell, the API, the service, the store, a driver or the twin (tests/unit/test_spc_contract.py).

:mod:`cellctl.quality.spc`: the closed-loop offset (an EWMA per axis, bounded, with drift and an
outlier gate); its values and their JSON form are in :mod:`cellctl.quality.spc_state`.
"""

from cellctl.quality import spc_state
from cellctl.quality.spc import SpcLoop, offset_pose
from cellctl.quality.spc_state import *  # noqa: F403 - the loop's values are the package's vocabulary

__all__ = ["SpcLoop", "offset_pose", *spc_state.__all__]
