"""The one error a calibration raises when its data cannot give a trustworthy result."""

from __future__ import annotations


class CalibrationRefused(ValueError):
    """The data cannot give a trustworthy calibration; the message says why and what to do.

    Attributes:
        part: the calibration part ("camera", "hand_eye", "laser", "pixel_map", "teaching").
        reason: a short machine-readable reason ("too_few_views", "one_rotation_axis",
            "board_not_found", "plane_too_few_directions", ...).
    """

    def __init__(self, part: str, reason: str, message: str) -> None:
        super().__init__(f"{part} calibration refused ({reason}): {message}")
        self.part = part
        self.reason = reason
        self.detail = message
