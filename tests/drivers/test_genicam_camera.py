"""The GenICam adapter against a real GenTL producer: TLSimu.cti from the genicam wheels 1.3.0-1.5.0.

TLSimu is a simulated camera (no exposure or gain nodes, software trigger); its Mono8 frame n is
the ramp (x + y + n) mod 256, which the tests use as the known truth.
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from genicam_support import GRAB_TIMED_OUT, MONO, TLSIMU, camera, ramp_offset  # noqa: F401 - camera is a fixture
from cellctl.ports import Camera, DeviceDisconnected, DeviceProtocolError, DeviceRejected, DeviceTimeout, Frame
from genicam_camera import GenicamCamera

TLSIMU_STAMP_WRAP_NS = 1_000_000_000
COLOUR = "SN_InterfaceA_1"


async def test_it_is_a_camera(camera: GenicamCamera) -> None:
    assert isinstance(camera, Camera)
    info = await camera.open()
    assert (info.model, info.serial_number) == ("TLSimuMono", MONO)


async def test_software_triggered_frames_are_new_and_true(camera: GenicamCamera) -> None:
    frames: list[Frame] = [await camera.grab(timeout_s=5.0) for _ in range(4)]
    offsets = [ramp_offset(f.image) for f in frames]
    assert all(f.image.dtype == np.uint8 and f.image.ndim == 2 for f in frames)
    # one trigger, one frame: consecutive frame ids and ramp offsets, nothing skipped or repeated
    assert [(o - offsets[0]) % 256 for o in offsets] == [0, 1, 2, 3]
    assert [f.frame_id - frames[0].frame_id for f in frames] == [0, 1, 2, 3]
    host = [f.timestamp_s for f in frames]
    device = [f.device_timestamp_ns for f in frames]
    assert host == sorted(host) and len(set(host)) == 4
    assert all(d is not None for d in device)
    # TLSimu stamps a buffer with the nanoseconds within the current second (measured: 400 frames spanned 3.8e6 ..
    # 999.6e6 ns and fell back twice), so four frames may straddle a wrap; each still comes after the last.
    steps = [(b - a) % TLSIMU_STAMP_WRAP_NS for a, b in zip(device, device[1:])]  # type: ignore[operator]
    assert all(0 < step < TLSIMU_STAMP_WRAP_NS // 2 for step in steps), device
    assert frames[0].exposure_us is None and frames[0].gain_db is None  # TLSimu has neither


async def test_free_run_frames(camera: GenicamCamera) -> None:
    free = GenicamCamera(cti_path=TLSIMU, serial_number=MONO, trigger_mode="free_run")
    try:
        first, second = await free.grab(timeout_s=5.0), await free.grab(timeout_s=5.0)
        ramp_offset(first.image)
        ramp_offset(second.image)
        assert second.frame_id > first.frame_id
    finally:
        await free.close()


async def test_frames_in_another_format_than_set_are_refused() -> None:
    # TLSimuColor accepts PixelFormat = Mono8 (and reads it back) but still delivers RGB8 buffers
    cam = GenicamCamera(cti_path=TLSIMU, serial_number=COLOUR)
    try:
        with pytest.raises(DeviceProtocolError, match="delivered RGB8 with PixelFormat set to Mono8"):
            await cam.grab(timeout_s=5.0)
    finally:
        await cam.close()


class DroppedTrigger:
    """The camera's acquirer, except that the software trigger never reaches the camera."""

    def __init__(self, acquirer: Any) -> None:
        self._acquirer = acquirer
        self.remote_device = SimpleNamespace(node_map=SimpleNamespace(TriggerSoftware=SimpleNamespace(execute=lambda: None)))

    def __getattr__(self, name: str) -> Any:
        return getattr(self._acquirer, name)


async def test_a_lost_trigger_ends_in_a_timeout(camera: GenicamCamera) -> None:
    await camera.grab(timeout_s=5.0)
    real = camera._acquirer  # noqa: SLF001 - swap in a trigger that is lost on the way
    camera._acquirer = DroppedTrigger(real)  # noqa: SLF001
    with pytest.raises(DeviceTimeout, match=GRAB_TIMED_OUT):
        await camera.grab(timeout_s=0.3)
    camera._acquirer = real  # noqa: SLF001
    ramp_offset((await camera.grab(timeout_s=5.0)).image)  # and the camera still works


async def test_ping(camera: GenicamCamera) -> None:
    assert 0.0 < await camera.ping(timeout_s=5.0) < 5.0
    assert 0.0 < await camera.ping(timeout_s=5.0) < 5.0


async def test_settings_the_camera_lacks_are_refused() -> None:
    for kwargs, message in (({"exposure_us": 1000.0}, "ExposureTime.*exposure_us"), ({"gain_db": 3.0}, "Gain.*gain_db")):
        cam = GenicamCamera(cti_path=TLSIMU, serial_number=MONO, **kwargs)  # type: ignore[arg-type]
        with pytest.raises(DeviceRejected, match=message):
            await cam.open()
        await cam.close()


async def test_choosing_the_camera() -> None:
    ambiguous = GenicamCamera(cti_path=TLSIMU)
    with pytest.raises(DeviceRejected, match="4 cameras match.*SN_InterfaceB_1"):
        await ambiguous.open()
    await ambiguous.close()
    missing = GenicamCamera(cti_path=TLSIMU, serial_number="NOPE")
    with pytest.raises(DeviceDisconnected, match="serial_number='NOPE'.*found: TLSimuMono"):
        await missing.grab(timeout_s=5.0)
    await missing.close()
    by_both = GenicamCamera(cti_path=TLSIMU, serial_number="SN_InterfaceB_0", user_id="Center")
    assert (await by_both.open()).serial_number == "SN_InterfaceB_0"
    await by_both.close()


async def test_a_missing_producer_names_the_setting(tmp_path: object) -> None:
    cam = GenicamCamera(cti_path="/opt/none/producer.cti")
    with pytest.raises(DeviceDisconnected, match="devices.camera.cti_path"):
        await cam.open()
    await cam.close()


async def test_close_twice_then_grab_is_refused(camera: GenicamCamera) -> None:
    await camera.grab(timeout_s=5.0)
    await camera.close()
    await camera.close()
    with pytest.raises(DeviceDisconnected, match="closed"):
        await camera.grab(timeout_s=1.0)


async def test_a_camera_of_another_size_than_calibrated_is_refused_when_opened() -> None:
    """TLSimu's Width/Height (read by harvesters, the peer) are 512 x 512: a lens calibrated for 2048 x 2048 refuses it."""
    wrong = GenicamCamera(cti_path=TLSIMU, serial_number=MONO, expected_size_px=(2048, 2048))
    with pytest.raises(DeviceRejected, match=r"Width x Height is 512 x 512 px, not the 2048 x 2048 px of layout.camera"):
        await wrong.open()
    await wrong.close()
    right = GenicamCamera(cti_path=TLSIMU, serial_number=MONO, expected_size_px=(512, 512))
    frame = await right.grab(timeout_s=5.0)
    assert frame.image.shape == (512, 512)
    await right.close()
