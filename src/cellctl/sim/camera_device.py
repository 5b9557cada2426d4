"""The twin's camera behind the Camera port: renders a frame of the simulated cell on each grab.

The scene comes from callbacks (the simulated cell supplies them): the camera's true pose and the
car body's placement at the moment of the trigger, and optionally the calibration targets in view
and the glass installed in the opening.
Rendering is CPU-bound (about 0.1 s for 2048 x 2048), so it runs in a worker thread; ``timeout_s``
bounds the whole grab. Given the twin's time line, a grab spends the camera's frame time on it
(exposure and transfer) and renders with the clock standing still: the rendering is the twin's
physics, not a wait of the cell's. A grab that times out raises DeviceTimeout; its render finishes in the
background and is discarded (a thread cannot be interrupted), and the next grab starts afresh.

Each frame draws its noise from its own generator, spawned in order from the camera's seeded
generator when the grab starts, so a sequence of grabs is reproducible for a seed regardless of
thread timing.
"""

from __future__ import annotations

import asyncio
import functools
import time
from typing import Callable, Sequence

import numpy as np

from cellctl.geometry.pose import Pose
from cellctl.ports import DeviceDisconnected, DeviceTimeout, Frame
from cellctl.sim.camera import AppliedDisturbances, CameraRenderer, RenderedFrame
from cellctl.sim.devices import check_timeout
from cellctl.sim.glass import InstalledGlass
from cellctl.sim.targets import PlacedTarget
from cellctl.sim.timeline import TwinTimeline
from cellctl.sim.world import World


class SimCamera:
    """A :class:`cellctl.ports.Camera` that renders the simulated cell.

    Args:
        renderer: the image formation (intrinsics, optics, sensor, disturbances).
        true_camera_pose: the camera's true pose T_B_C now.
        world: the car body's true placement now (None: no car body in view).
        rng: seeded generator; each frame spawns its own child from it.
        targets: the calibration targets in view now (default: none).
        glass: the glass installed in the car body's opening now, or None (default: never one).
        name: the device's name in messages.
        timeline: the twin's time line (None: a grab takes the rendering's real time, no more).
        frame_time_s: simulated seconds from trigger to frame on ``timeline`` (scaled by its time_scale in real time).
    """

    def __init__(
        self,
        renderer: CameraRenderer,
        true_camera_pose: Callable[[], Pose],
        world: Callable[[], World | None],
        rng: np.random.Generator,
        *,
        targets: Callable[[], Sequence[PlacedTarget]] | None = None,
        glass: Callable[[], InstalledGlass | None] | None = None,
        name: str = "camera",
        timeline: TwinTimeline | None = None,
        frame_time_s: float = 0.0,
    ) -> None:
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"{name}: rng must be a numpy Generator (np.random.default_rng(seed))")
        self._renderer = renderer
        self._pose = true_camera_pose
        self._world = world
        self._targets = targets
        self._glass = glass
        self._rng = rng
        self.name = name
        self._timeline = timeline
        self._frame_time_s = float(frame_time_s)
        self._frame_id = 0
        self._closed = False
        self.last_applied: AppliedDisturbances | None = None
        self.last_pose: Pose | None = None

    def identity(self) -> dict[str, str]:
        """The twin's camera (Identified port)."""
        i = self._renderer.intrinsics
        return {"kind": "twin camera", "size_px": f"{i.width_px}x{i.height_px}"}

    def _check_open(self) -> None:
        if self._closed:
            raise DeviceDisconnected(self.name, "the camera is closed; create a new device to reconnect")

    async def grab(self, *, timeout_s: float) -> Frame:
        """Trigger, render the scene as it is now, and return the frame.

        Raises DeviceTimeout when the frame is not ready within ``timeout_s``, DeviceDisconnected
        after close().
        """
        timeout_s = check_timeout(self.name, timeout_s)
        self._check_open()
        trigger_ns = time.monotonic_ns()
        pose = np.array(self._pose(), dtype=float)
        world = self._world()
        targets = tuple(self._targets()) if self._targets is not None else ()
        glass = self._glass() if self._glass is not None and world is not None else None
        frame_rng = self._rng.spawn(1)[0]
        self._frame_id += 1
        frame_id = self._frame_id
        try:
            async with asyncio.timeout(timeout_s):  # in the caller's task: a cancel leaves no frame's error unread
                rendered = await self._frame(pose, world, targets, frame_rng, glass)
        except TimeoutError:
            raise DeviceTimeout(self.name, f"frame {frame_id} not ready within {timeout_s:g} s") from None
        self._check_open()
        self.last_applied = rendered.applied
        self.last_pose = pose
        return Frame(
            image=rendered.image, timestamp_s=time.monotonic(), frame_id=frame_id, device_timestamp_ns=trigger_ns
        )

    async def _frame(
        self, pose: Pose, world: World | None, targets: tuple[PlacedTarget, ...], rng: np.random.Generator,
        glass: InstalledGlass | None,
    ) -> RenderedFrame:
        """Expose and transfer (the frame time on the time line), then render with the cell's clock standing still."""
        work = functools.partial(self._renderer.render, pose, world, targets=targets, rng=rng, glass=glass)
        if self._timeline is None:
            return await asyncio.to_thread(work)
        self._timeline.waited(self._frame_time_s, "camera frames")
        await asyncio.sleep(self._frame_time_s * self._timeline.time_scale)
        with self._timeline.unclocked():
            return await asyncio.to_thread(work)

    async def ping(self, *, timeout_s: float) -> float:
        """A harmless round trip; returns its duration in seconds."""
        check_timeout(self.name, timeout_s)
        self._check_open()
        start = time.perf_counter()
        await asyncio.sleep(0)
        return time.perf_counter() - start

    async def close(self) -> None:
        """Release the camera. Safe to call twice."""
        self._closed = True
