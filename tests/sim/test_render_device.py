"""SimCamera: the twin camera behind the Camera port."""

from __future__ import annotations

import asyncio
import time

import numpy as np
import pytest

from cellctl.config.mounting import CameraIntrinsics
from cellctl.config.render import RenderConfig
from cellctl.config.sim import WorldConfig
from cellctl.geometry.pose import make_pose
from cellctl.ports import Camera, DeviceDisconnected, DeviceTimeout, Frame
from cellctl.sim.camera import AppliedDisturbances, CameraRenderer, RenderedFrame
from cellctl.sim.camera_device import SimCamera
from cellctl.sim.image_truth import camera_pose_seeing_corner, corner_truth
from cellctl.sim.targets import Checkerboard, PlacedTarget
from cellctl.sim.timeline import TwinTimeline
from cellctl.sim.world import World, nominal_world

WORLD = nominal_world(WorldConfig())


@pytest.fixture(scope="module")
def renderer() -> CameraRenderer:
    return CameraRenderer(CameraIntrinsics(), RenderConfig())


class Scene:
    """A stand-in for the simulated cell: the camera pose and the car body can be changed."""

    def __init__(self, renderer: CameraRenderer, corner_px: tuple[float, float]) -> None:
        self.renderer = renderer
        self.world: World = WORLD
        self.pose = camera_pose_seeing_corner(renderer.camera, WORLD, corner_px)
        self.pose_calls = 0

    def true_camera_pose(self) -> np.ndarray:
        self.pose_calls += 1
        return self.pose

    def current_world(self) -> World:
        return self.world


def _camera(renderer: CameraRenderer, scene: Scene, seed: int = 1) -> SimCamera:
    return SimCamera(renderer, scene.true_camera_pose, scene.current_world, np.random.default_rng(seed))


async def test_grab_returns_numbered_frames_of_the_scene(renderer: CameraRenderer) -> None:
    scene = Scene(renderer, (1500.0, 560.0))
    cam = _camera(renderer, scene)
    assert isinstance(cam, Camera)
    first = await cam.grab(timeout_s=10.0)
    second = await cam.grab(timeout_s=10.0)
    for frame in (first, second):
        assert isinstance(frame, Frame)
        assert frame.image.shape == (2048, 2048) and frame.image.dtype == np.uint8
        assert frame.device_timestamp_ns is not None
    assert (first.frame_id, second.frame_id) == (1, 2)
    assert second.timestamp_s > first.timestamp_s
    assert not np.array_equal(first.image, second.image)  # fresh noise per frame
    assert scene.pose_calls == 2  # the pose is read at each trigger
    # The picture shows the scene: wall above the top edge, the dark opening below-left of the corner.
    truth = corner_truth(renderer.camera, scene.pose, WORLD)
    u, v = truth.corner_px
    assert first.image[int(v) - 60, int(u) - 600] > 100 and first.image[int(v) + 600, int(u) - 600] < 40
    await cam.close()


async def test_frames_follow_the_pose_at_the_trigger(renderer: CameraRenderer) -> None:
    scene = Scene(renderer, (1500.0, 560.0))
    cam = _camera(renderer, scene)
    before = await cam.grab(timeout_s=10.0)
    scene.pose = scene.pose @ make_pose(np.eye(3), [10.0, 0.0, 0.0])  # camera 10 mm right: scene shifts left
    after = await cam.grab(timeout_s=10.0)
    row = 1200
    edge_before = np.flatnonzero(np.diff((before.image[row] > 85).astype(int)))[-1]
    edge_after = np.flatnonzero(np.diff((after.image[row] > 85).astype(int)))[-1]
    assert edge_before - edge_after == pytest.approx(10.0 * 5249.574 / 400.0, abs=3.0)


async def test_same_seed_same_frames(renderer: CameraRenderer) -> None:
    scene = Scene(renderer, (1400.0, 700.0))
    a, b = _camera(renderer, scene, seed=42), _camera(renderer, scene, seed=42)
    for _ in range(2):
        fa, fb = await a.grab(timeout_s=10.0), await b.grab(timeout_s=10.0)
        assert np.array_equal(fa.image, fb.image)


async def test_a_slow_frame_times_out_and_the_camera_recovers(renderer: CameraRenderer) -> None:
    scene = Scene(renderer, (1500.0, 560.0))
    cam = _camera(renderer, scene)
    with pytest.raises(DeviceTimeout, match="not ready within"):
        await cam.grab(timeout_s=1e-4)  # a render takes tens of milliseconds
    frame = await cam.grab(timeout_s=10.0)
    assert frame.frame_id == 2


async def test_close_ping_and_bad_timeouts(renderer: CameraRenderer) -> None:
    scene = Scene(renderer, (1500.0, 560.0))
    cam = _camera(renderer, scene)
    assert 0.0 <= await cam.ping(timeout_s=1.0) < 1.0
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="timeout_s"):
            await cam.grab(timeout_s=bad)
    await cam.close()
    await cam.close()  # safe twice
    with pytest.raises(DeviceDisconnected):
        await cam.grab(timeout_s=1.0)
    with pytest.raises(DeviceDisconnected):
        await cam.ping(timeout_s=1.0)


async def test_targets_in_view_are_rendered(renderer: CameraRenderer) -> None:
    board = Checkerboard(inner_corners=(9, 6), square_mm=10.0)
    placed = PlacedTarget(board, make_pose(np.eye(3), [-40.0, -25.0, 420.0]))
    cam = SimCamera(renderer, lambda: np.eye(4), lambda: None, np.random.default_rng(3), targets=lambda: [placed])
    frame = await asyncio.wait_for(cam.grab(timeout_s=10.0), 20.0)
    u, v = renderer.project(placed.points_B()[:1], np.eye(4))[0]
    # Around the first inner corner: the black top-left cell and the white cell beside it.
    assert frame.image[int(v) - 40, int(u) - 40] < 60 and frame.image[int(v) - 40, int(u) + 40] > 150


class _SlowRenderer:
    """Renders a black frame after ``seconds`` of the host's time (the twin's physics at its slowest)."""

    def __init__(self, renderer: CameraRenderer, seconds: float) -> None:
        self.intrinsics, self._seconds = renderer.intrinsics, seconds

    def render(self, *args: object, **kwargs: object) -> RenderedFrame:
        time.sleep(self._seconds)
        return RenderedFrame(np.zeros((8, 8), np.uint8), AppliedDisturbances(1.0, 1.0, 200.0, 20.0))


async def test_a_grab_takes_the_frame_time_on_the_cells_clock_not_the_rendering(renderer: CameraRenderer) -> None:
    line = TwinTimeline(0.001)
    scene = Scene(renderer, (1500.0, 560.0))
    cam = SimCamera(
        _SlowRenderer(renderer, 0.4), scene.true_camera_pose, scene.current_world, np.random.default_rng(1),  # type: ignore[arg-type]
        timeline=line, frame_time_s=0.045,
    )
    before = line.now()
    await cam.grab(timeout_s=10.0)
    assert line.now() - before == pytest.approx(0.045, abs=0.1)  # not 0.4 s: a real cell does not wait for the twin
