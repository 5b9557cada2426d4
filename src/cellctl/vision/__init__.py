"""Paper section 4: the window corner in the image, pixel to millimetre, and the in-plane offset.

- :func:`detect_corner` (corner): the corner (u, v) and angle theta, with quality figures, or a
  refusal with its reason.
- :func:`checkerboard_scale` (scale): the pixel scale s of eq. 15.
- :func:`fit_affine_map`, :func:`find_dot_grid` (ninepoint): the nine-point pixel-to-mm map.
- :func:`offset_from_scale`, :func:`offset_from_map` (offset): eq. 16 turned into T'.
- :func:`annotate` (annotate): the annotated PNG.
"""

from cellctl.vision.annotate import annotate
from cellctl.vision.corner import CornerFeatures, CornerMeasurement, EdgeMeasurement, detect_corner
from cellctl.vision.lens import Lens
from cellctl.vision.ninepoint import AffineMap, NinePointError, find_dot_grid, fit_affine_map
from cellctl.vision.offset import Deviation, deviation, offset_from_map, offset_from_scale
from cellctl.vision.quality import Check, EdgeQuality, Refusal
from cellctl.vision.scale import PixelScale, ScaleCalibrationError, checkerboard_scale, scale_from_corners

__all__ = [
    "AffineMap",
    "Check",
    "CornerFeatures",
    "CornerMeasurement",
    "Deviation",
    "EdgeMeasurement",
    "EdgeQuality",
    "Lens",
    "NinePointError",
    "PixelScale",
    "Refusal",
    "ScaleCalibrationError",
    "annotate",
    "checkerboard_scale",
    "deviation",
    "detect_corner",
    "find_dot_grid",
    "fit_affine_map",
    "offset_from_map",
    "offset_from_scale",
    "scale_from_corners",
]
