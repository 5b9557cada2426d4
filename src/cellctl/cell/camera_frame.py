"""A cycle's camera grab, checked against the calibrated lens.

A camera that delivers another frame size than the lens was calibrated for (a swapped camera, one
back from a power cycle with another ROI or binning) fails the cycle with the camera-grab alarm
naming both sizes and what to check, not later in the vision code as a software fault.
"""

from __future__ import annotations

import numpy as np

from cellctl.cell.cycle_failure import CycleFailed
from cellctl.domain import AlarmCode, CycleStep
from cellctl.ports import Camera, DeviceError, Frame
from cellctl.vision import Lens


def frame_size_problem(image: np.ndarray, lens: Lens) -> str | None:
    """Why ``image`` (height, width) cannot be measured with ``lens``, or None if it has the lens's size."""
    height, width = image.shape[:2]
    if (height, width) == (lens.height_px, lens.width_px):
        return None
    return (
        f"the camera delivers {width} x {height} px frames but the lens is calibrated for {lens.width_px} x "
        f"{lens.height_px} px: check the camera's Width/Height, binning and decimation, and that "
        f"devices.camera.serial_number names this cell's camera; a replaced camera is recalibrated "
        f"(`cellctl calibrate camera` and the steps after it)"
    )


async def grab_checked(camera: Camera, lens: Lens, step: CycleStep, *, timeout_s: float, what: str) -> Frame:
    """One frame of ``camera`` (timeout in s) of ``lens``'s size; else CycleFailed in ``step`` with the
    camera-grab alarm, its reason starting with ``what`` for a failed grab."""
    try:
        frame = await camera.grab(timeout_s=timeout_s)
    except DeviceError as err:
        raise CycleFailed(step, AlarmCode.CAMERA_GRAB_FAILED, f"{what}: {err}") from err
    problem = frame_size_problem(frame.image, lens)
    if problem is not None:
        raise CycleFailed(step, AlarmCode.CAMERA_GRAB_FAILED, problem)
    return frame
