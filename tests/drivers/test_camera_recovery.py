"""The GenICam adapter after faults, against TLSimu.cti (genicam 1.3.0-1.5.0): it reopens after a GenTL failure, and a
grab never returns the frame of an earlier trigger. Known truth: TLSimu's Mono8 frame n is the ramp (x + y + n) mod 256,
n counting the frames the simulated camera produced."""

from __future__ import annotations

import asyncio
import threading
import time
from types import SimpleNamespace
from typing import Any

import pytest

from genicam_support import GRAB_TIMED_OUT, MONO, TLSIMU, camera, ramp_offset  # noqa: F401 - camera is a fixture
from cellctl.ports import DeviceDisconnected, DeviceTimeout
from genicam_camera import GenicamCamera

LATENCY_S = 0.15  # a frame lands this long after its trigger (exposure, read-out, transfer)


class LostDevice:
    """The camera's acquirer, except that its device has gone (a GenTL call fails, as when a cable is pulled)."""

    def __init__(self, acquirer: Any) -> None:
        self._acquirer = acquirer

    @property
    def remote_device(self) -> Any:
        raise RuntimeError("GenTL: device lost")

    def __getattr__(self, name: str) -> Any:
        return getattr(self._acquirer, name)


class SlowFrames:
    """The camera's acquirer, except that each frame lands LATENCY_S after its software trigger."""

    def __init__(self, acquirer: Any) -> None:
        self._acquirer = acquirer
        self.triggers = 0
        self.timers: list[threading.Timer] = []

        def execute() -> None:
            self.triggers += 1
            timer = threading.Timer(LATENCY_S, acquirer.remote_device.node_map.TriggerSoftware.execute)
            self.timers.append(timer)
            timer.start()

        self.remote_device = SimpleNamespace(node_map=SimpleNamespace(TriggerSoftware=SimpleNamespace(execute=execute)))

    def __getattr__(self, name: str) -> Any:
        return getattr(self._acquirer, name)


async def test_after_a_gentl_failure_the_next_call_reopens_the_camera(camera: GenicamCamera) -> None:
    ramp_offset((await camera.grab(timeout_s=5.0)).image)
    camera._acquirer = LostDevice(camera._acquirer)  # noqa: SLF001 - the device fails once
    with pytest.raises(DeviceDisconnected, match="device lost.*the next call reopens the camera"):
        await camera.ping(timeout_s=2.0)
    # the camera is back: without a restart, the next ping and grab reach it again (a reopened TLSimu starts over at 0)
    assert 0.0 < await camera.ping(timeout_s=5.0) < 5.0
    assert camera.info is not None and camera.info.serial_number == MONO
    assert ramp_offset((await camera.grab(timeout_s=5.0)).image) == 0


async def test_a_late_frame_of_a_timed_out_grab_is_not_the_next_grabs(camera: GenicamCamera) -> None:
    before = ramp_offset((await camera.grab(timeout_s=5.0)).image)
    slow = SlowFrames(camera._acquirer)  # noqa: SLF001
    camera._acquirer = slow  # noqa: SLF001
    with pytest.raises(DeviceTimeout, match=GRAB_TIMED_OUT):
        await camera.grab(timeout_s=0.05)  # its frame is still on the way when the call gives up
    began = time.monotonic()
    frame = await camera.grab(timeout_s=2.0)
    # the camera's second frame since `before` is this grab's own: taken after the call began, not the late first one
    assert ramp_offset(frame.image) == (before + 2) % 256
    assert frame.timestamp_s - began >= LATENCY_S
    assert slow.triggers == 2
    for timer in slow.timers:
        timer.join(1.0)
    camera._acquirer = slow._acquirer  # noqa: SLF001


async def test_a_trigger_whose_frame_never_comes_is_given_up() -> None:
    cam = GenicamCamera(cti_path=TLSIMU, serial_number=MONO, frame_lost_after_s=0.2)
    try:
        before = ramp_offset((await cam.grab(timeout_s=5.0)).image)
        real = cam._acquirer  # noqa: SLF001 - a trigger that never reaches the camera
        cam._acquirer = SimpleNamespace(  # noqa: SLF001
            num_buffers=real.num_buffers, try_fetch=real.try_fetch,
            remote_device=SimpleNamespace(node_map=SimpleNamespace(TriggerSoftware=SimpleNamespace(execute=lambda: None))),
        )
        with pytest.raises(DeviceTimeout, match=GRAB_TIMED_OUT):
            await cam.grab(timeout_s=0.1)
        cam._acquirer = real  # noqa: SLF001
        began = time.monotonic()
        assert ramp_offset((await cam.grab(timeout_s=2.0)).image) == (before + 1) % 256  # no frame was skipped
        assert time.monotonic() - began < 1.0  # waited out the lost trigger (0.2 s), not the grab's timeout
    finally:
        await asyncio.wait_for(cam.close(), 10.0)
