"""Calibration and teaching (paper 2.2, 4.1, 4.3 step 1) and the versioned calibration set.

- camera: intrinsics by Zhang's method; board: finding the checkerboard.
- hand_eye: T_H_C by our Tsai-Lenz and OpenCV's five methods, compared; poses: pose plans.
- laser: r and l from plane constraints; pixel_map: scale s and the nine-point map; teach: T0.
- calibration_set: the set, its validation, history and :func:`check_ready`.
- dataset, collect, runs, compute, twin, cli: data on disk, collection through the ports, the
  simulated cell, and the ``cellctl calibrate``/``cellctl teach`` commands.
"""

from cellctl.calibration.calibration_set import CalibrationSet, CalibrationSetError, CalibrationStore
from cellctl.calibration.errors import CalibrationRefused
from cellctl.calibration.readiness import check_ready

__all__ = ["CalibrationRefused", "CalibrationSet", "CalibrationSetError", "CalibrationStore", "check_ready"]
