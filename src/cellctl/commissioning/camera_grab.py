"""A commissioning grab, checked against the frame size the procedure computes with.

The camera procedure computes the lens at ``layout.camera``'s size (its dataset's ``image_size``); every
later procedure measures with the calibrated lens. A camera that delivers another size (binning or an
ROI left on, a swapped camera) is refused at its first frame, naming both sizes and the setting to
change, rather than computed into a lens or a hand-eye that every cycle then refuses.
"""

from __future__ import annotations

from cellctl.calibration.errors import CalibrationRefused
from cellctl.commissioning.context import JobContext
from cellctl.ports import Frame


def expected_frame_px(ctx: JobContext, part: str) -> tuple[tuple[int, int], str]:
    """(width, height) in px a frame of procedure ``part`` must have, and what says so."""
    cal = ctx.calibration
    if part != "camera" and cal is not None and cal.usable("camera"):
        w, h = cal.image_size()
        return (int(w), int(h)), "the camera calibration is for"
    lay = ctx.config.layout.camera
    return (lay.width_px, lay.height_px), "layout.camera is"


def frame_size_refusal(ctx: JobContext, part: str, width_px: int, height_px: int) -> CalibrationRefused | None:
    """Why a frame of ``width_px`` x ``height_px`` cannot serve procedure ``part``, or None."""
    (w, h), source = expected_frame_px(ctx, part)
    if (width_px, height_px) == (w, h):
        return None
    said = f"the camera delivers {width_px} x {height_px} px frames but {source} {w} x {h} px: "
    if source.startswith("layout"):
        fix = (f"set the camera's Width/Height, binning and decimation to {w} x {h} px, or set layout.camera's "
               "width_px, height_px, fx, fy, cx and cy to the camera's frame (a b x b binning divides each by b)")  # fmt: skip
    else:
        fix = ("check the camera's Width/Height, binning and decimation, and that devices.camera.serial_number names "
               "this cell's camera; a replaced camera is calibrated first (`cellctl calibrate camera`)")  # fmt: skip
    return CalibrationRefused(part, "frame_size", said + fix)


async def grab(ctx: JobContext, part: str) -> Frame:
    """One frame for procedure ``part`` (shown on the dashboard), refused when its size does not fit."""
    frame = await ctx.devices.camera.grab(timeout_s=ctx.motion.grab_timeout_s)
    ctx.on_frame(frame)
    height, width = frame.image.shape[:2]
    refusal = frame_size_refusal(ctx, part, width, height)
    if refusal is not None:
        raise refusal
    return frame
