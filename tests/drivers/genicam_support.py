"""The GenICam tests' camera: TLSimu.cti from the genicam wheels 1.3.0-1.5.0, a real GenTL producer.

TLSimu is a simulated camera (no exposure or gain nodes, software trigger); its Mono8 frame n is the
ramp (x + y + n) mod 256, which the tests use as the known truth. Importing this skips the importing
module where the camera extra or the producer is missing.
"""

from __future__ import annotations

import os
from collections.abc import AsyncIterator

import numpy as np
import pytest

pytest.importorskip("harvesters.core", reason="the optional extra 'camera' (harvesters, genicam) is not installed")
genicam = pytest.importorskip("genicam", reason="the optional extra 'camera' (harvesters, genicam) is not installed")

from genicam_camera import GenicamCamera  # noqa: E402

TLSIMU = os.path.join(os.path.dirname(genicam.__file__), "TLSimu.cti")
if not os.path.isfile(TLSIMU):
    pytest.skip(
        f"genicam {getattr(genicam, '__version__', '?')} has no TLSimu.cti (only 1.3.0-1.5.0 ship it): "
        "install the camera extra's pin 'genicam>=1.3,<1.5.1'",
        allow_module_level=True,
    )

MONO = "SN_InterfaceA_0"
# A grab that times out says so in one of two ways, depending on which side of the worker thread saw the deadline
# first (the worker's wait for a buffer: "no frame within the grab's timeout"; the event loop's: "grabbing a frame took
# longer than"): on a loaded machine either comes first.
GRAB_TIMED_OUT = "no frame within the grab's timeout|grabbing a frame took longer than"


def ramp_offset(image: np.ndarray) -> int:
    """The n of TLSimu's ramp (x + y + n) mod 256; fails if the image is not that ramp."""
    n = int(image[0, 0])
    yy, xx = np.indices(image.shape)
    np.testing.assert_array_equal(image, ((xx + yy + n) % 256).astype(np.uint8))
    return n


@pytest.fixture
async def camera() -> AsyncIterator[GenicamCamera]:
    cam = GenicamCamera(cti_path=TLSIMU, serial_number=MONO, timeout_s=10.0)
    yield cam
    await cam.close()
