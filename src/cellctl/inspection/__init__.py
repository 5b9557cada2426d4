"""The post-install inspection's math: flush from laser points, the measured install deviation.

Pure functions on numpy arrays (no I/O); the cycle's inspect step (:mod:`cellctl.cell.inspect_step`)
drives the devices and calls them.
"""

from cellctl.inspection.deviation import MeasuredDeviation, measured_deviation
from cellctl.inspection.flush import FlushError, FlushResult, fit_flush

__all__ = ["FlushError", "FlushResult", "MeasuredDeviation", "fit_flush", "measured_deviation"]
