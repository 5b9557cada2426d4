"""Camera buffers to 8-bit images (pure; runs without the camera extra)."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from cellctl.ports import DeviceDisconnected
from genicam_camera import GenicamCamera, to_mono8


def test_mono8_is_reshaped_and_copied() -> None:
    flat = np.arange(12, dtype=np.uint8)
    image = to_mono8(flat, width=4, height=3, pixel_format="Mono8")
    assert image.shape == (3, 4) and image.dtype == np.uint8
    assert image[1, 0] == 4 and image[2, 3] == 11
    flat[:] = 0
    assert image[2, 3] == 11  # a copy: the buffer goes back to the producer


@pytest.mark.parametrize(("fmt", "bits"), [("Mono10", 10), ("Mono12", 12), ("Mono16", 16)])
def test_deeper_formats_keep_their_top_bits(fmt: str, bits: int) -> None:
    rng = np.random.default_rng(7)
    raw = rng.integers(0, 1 << bits, size=6 * 5, dtype=np.uint16)
    image = to_mono8(raw, width=6, height=5, pixel_format=fmt)
    assert image.dtype == np.uint8
    np.testing.assert_array_equal(image.reshape(-1), (raw >> (bits - 8)).astype(np.uint8))
    assert to_mono8(np.array([(1 << bits) - 1], np.uint16), 1, 1, fmt)[0, 0] == 255


@pytest.mark.parametrize(
    ("data", "width", "height", "fmt", "message"),
    [
        (np.zeros(12, np.uint8), 4, 3, "RGB8", "not an unpacked monochrome"),
        (np.zeros(12, np.uint8), 4, 3, "Mono12Packed", "pixel_format"),
        (np.zeros(11, np.uint8), 4, 3, "Mono8", "expected 4 x 3"),
        (np.zeros(12, np.uint16), 4, 3, "Mono8", "dtype"),
        (np.full(12, 4096, np.uint16), 4, 3, "Mono12", "more than 12 bits"),
        (np.zeros(0, np.uint8), 0, 3, "Mono8", "not positive"),
    ],
)
def test_what_cannot_be_converted_is_refused(data: np.ndarray, width: int, height: int, fmt: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        to_mono8(data, width, height, fmt)


async def test_a_missing_harvesters_names_the_extra(monkeypatch: pytest.MonkeyPatch, tmp_path: object) -> None:
    monkeypatch.setitem(sys.modules, "harvesters.core", None)  # import fails as if not installed
    camera = GenicamCamera(cti_path="/nonexistent/producer.cti")
    with pytest.raises(DeviceDisconnected, match=r"cellctl\[camera\]"):
        await camera.grab(timeout_s=2.0)
    await camera.close()


def test_bad_arguments_are_refused() -> None:
    with pytest.raises(ValueError, match="pixel_format"):
        GenicamCamera(cti_path="x.cti", pixel_format="BayerRG8")
    with pytest.raises(ValueError, match="trigger_mode"):
        GenicamCamera(cti_path="x.cti", trigger_mode="line1")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="exposure_us"):
        GenicamCamera(cti_path="x.cti", exposure_us=0.0)
    with pytest.raises(ValueError, match="gain_db"):
        GenicamCamera(cti_path="x.cti", gain_db=float("nan"))
    with pytest.raises(ValueError, match="cti_path"):
        GenicamCamera(cti_path="")
