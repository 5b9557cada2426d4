"""Camera buffers to 8-bit grey images (pure: numpy in, numpy out)."""

from __future__ import annotations

from typing import Final, Mapping

import numpy as np
from numpy.typing import NDArray

# Unpacked monochrome GenICam pixel formats and their significant bits.
MONO_BITS: Final[Mapping[str, int]] = {"Mono8": 8, "Mono10": 10, "Mono12": 12, "Mono16": 16}


def to_mono8(data: NDArray[np.generic], width: int, height: int, pixel_format: str) -> NDArray[np.uint8]:
    """A (height, width) uint8 image from a buffer's flat pixel data, always a copy.

    Deeper formats keep their 8 most significant bits. Packed, signed, Bayer and colour formats
    are refused with the fix (choose an unpacked Mono format), never reinterpreted.
    """
    bits = MONO_BITS.get(pixel_format)
    if bits is None:
        raise ValueError(
            f"pixel format {pixel_format!r} is not an unpacked monochrome format "
            f"({', '.join(MONO_BITS)}); set devices.camera.pixel_format to one the camera offers"
        )
    if width <= 0 or height <= 0:
        raise ValueError(f"image size {width} x {height} is not positive")
    flat = np.asarray(data).reshape(-1)
    if flat.size != width * height:
        raise ValueError(f"buffer holds {flat.size} pixels, expected {width} x {height} = {width * height}")
    image = flat.reshape(height, width)
    if bits == 8:
        if image.dtype != np.uint8:
            raise ValueError(f"Mono8 buffer has dtype {image.dtype}, expected uint8")
        return image.copy()
    if image.dtype not in (np.uint16, np.uint8):
        raise ValueError(f"{pixel_format} buffer has dtype {image.dtype}, expected uint16")
    wide = image.astype(np.uint16, copy=False)
    if int(wide.max(initial=0)) >= 1 << bits:
        raise ValueError(f"{pixel_format} buffer has values of more than {bits} bits: the pixel format is not what it says")
    return (wide >> (bits - 8)).astype(np.uint8)
