"""The fake ABB controller: the RAPID line server and the robot side of EGM around one fake robot.

Run it in its own process (``python -m abb_robot.fake``), or in-process for tests with
:meth:`FakeController.start_in_thread`, which gives it its own event loop in a thread so that it
never shares timing with the code under test.
"""

from __future__ import annotations

import asyncio
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypeVar

from abb_robot.fake.egm_robot import EgmDynamics, EgmRobotSide, EgmSessionStats
from abb_robot.fake.egm_stream import EgmStreamStats
from abb_robot.fake.model import RobotModel, SimpleArmModel
from abb_robot.fake.rapid_server import RapidLineServer, ServerIdentity
from abb_robot.fake.robot import FakeRobot
from cellctl.ports import CartesianPose

T = TypeVar("T")

# A comfortable start pose for the default model: flange 2 m in front of the base, 1.5 m up,
# tool z pointing forward (+x).
DEFAULT_HOME = CartesianPose((2000.0, 0.0, 1500.0), (0.7071067811865476, 0.0, 0.7071067811865476, 0.0))


@dataclass
class FakeControllerConfig:
    """Everything the fake controller needs besides its model.

    Attributes:
        rapid_host, rapid_port: where the line server listens (port 0 picks a free one).
        egm_sensor_host, egm_sensor_port: the sensor (PC) address EGM datagrams go to, like the
            controller's UDPUC "Remote Address" and "Remote Port Number"; None disables EGM.
        egm: EGM timing and following behaviour.
        egm_loss_out, egm_loss_in: seeded drop rates of outgoing EgmRobot (sessions and the position
            stream) and incoming EgmSensor.
        egm_stream_jitter_s: each position-stream datagram leaves up to this long after its sample
            (s, uniform, seeded): transport jitter for tests.
        egm_uptime_ms: the controller's uptime clock (``header.tm``, ms) at start; None: a seeded random one.
        seed: seed of the loss generator (the model has its own).
        idle_timeout_s: a client that sends nothing for this long is dropped.
        time_scale: motion durations are multiplied by this.
        home: flange pose at start.
        tools, wobjs: extra tool (TCP in flange) and work object (frame in base) definitions.
        identity: what HELLO reports.
        stats_file: where each EGM session's statistics are written as JSON.
        egm_rt_priority: SCHED_FIFO priority of the EGM thread (None: normal scheduling).
        gripper_hold: the gripper's vacuum output at start (True: on, holding a glass).
        gripper_settle_s: what GRIP waits after switching the output before it answers (the
            module's ``grip_settle``), multiplied by ``time_scale`` as motions are.
        on_gripper: physics called with the new output (True: hold, False: release) whenever
            GRIP switches it, from the controller's thread under the robot's lock (as the
            model's ``execute`` is), so a twin can let go of its glass. None: nothing reacts.
    """

    rapid_host: str = "127.0.0.1"
    rapid_port: int = 0
    egm_sensor_host: str = "127.0.0.1"
    egm_sensor_port: int | None = None
    egm: EgmDynamics = field(default_factory=EgmDynamics)
    egm_loss_out: float = 0.0
    egm_loss_in: float = 0.0
    egm_stream_jitter_s: float = 0.0
    egm_uptime_ms: int | None = None
    seed: int = 0
    idle_timeout_s: float = 10.0
    time_scale: float = 1.0
    home: CartesianPose = DEFAULT_HOME
    tools: dict[str, CartesianPose] = field(default_factory=dict)
    wobjs: dict[str, CartesianPose] = field(default_factory=dict)
    identity: ServerIdentity = field(default_factory=ServerIdentity)
    stats_file: str | None = None
    egm_rt_priority: int | None = None
    gripper_hold: bool = False
    gripper_settle_s: float = 0.5
    on_gripper: Callable[[bool], None] | None = None


class FakeController:
    """One fake controller: construct, then :meth:`start` (in a loop) or :meth:`start_in_thread`."""

    def __init__(self, config: FakeControllerConfig, model: RobotModel | None = None) -> None:
        self.config = config
        self.model = model if model is not None else SimpleArmModel(seed=config.seed)
        if not (math.isfinite(config.gripper_settle_s) and config.gripper_settle_s >= 0):
            raise ValueError(f"gripper_settle_s must be a finite number >= 0, got {config.gripper_settle_s}")
        self.robot = FakeRobot(
            self.model, config.home, tools=config.tools, wobjs=config.wobjs, time_scale=config.time_scale,
            gripper_hold=config.gripper_hold, on_gripper=config.on_gripper,
        )
        self.egm: EgmRobotSide | None = None
        self.server: RapidLineServer | None = None
        self.rapid_port: int | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._stopped: asyncio.Event | None = None

    async def start(self) -> int:
        """Start serving in the running loop; returns the RAPID port."""
        cfg = self.config
        if cfg.egm_sensor_port is not None:
            self.egm = EgmRobotSide(self.robot, cfg)
        self.server = RapidLineServer(self.robot, self.egm, cfg)
        self.rapid_port = await self.server.start(cfg.rapid_host, cfg.rapid_port)
        self._loop = asyncio.get_running_loop()
        return self.rapid_port

    async def aclose(self) -> None:
        """Stop serving and end the EGM side."""
        if self.server is not None:
            await self.server.close()
        if self.egm is not None:
            self.egm.close()

    # -- in-process use -----------------------------------------------------------------------

    def start_in_thread(self, timeout_s: float = 5.0) -> int:
        """Run the controller on its own event loop in a daemon thread; returns the RAPID port."""
        ready = threading.Event()
        errors: list[BaseException] = []

        def run() -> None:
            loop = asyncio.new_event_loop()
            asyncio.set_event_loop(loop)
            self._stopped = asyncio.Event()

            async def main() -> None:
                try:
                    await self.start()
                except BaseException as exc:  # noqa: BLE001 - reported to the starting thread
                    errors.append(exc)
                    ready.set()
                    return
                ready.set()
                assert self._stopped is not None
                await self._stopped.wait()
                await self.aclose()

            loop.run_until_complete(main())
            # As asyncio.run ends: what still runs (a connection's session) is cancelled and finished on this loop,
            # not left for the garbage collector to close after the loop has gone.
            left = asyncio.all_tasks(loop)
            for task in left:
                task.cancel()
            loop.run_until_complete(asyncio.gather(*left, return_exceptions=True))
            loop.run_until_complete(loop.shutdown_asyncgens())
            loop.close()

        self._thread = threading.Thread(target=run, name="fake-abb-controller", daemon=True)
        self._thread.start()
        if not ready.wait(timeout_s):
            raise TimeoutError("fake controller did not start in time")
        if errors:
            raise errors[0]
        assert self.rapid_port is not None
        return self.rapid_port

    def stop_thread(self, timeout_s: float = 5.0) -> None:
        """Stop the controller's thread (a second call, or one after the thread ended, does nothing)."""
        if self._loop is not None and self._stopped is not None and self._thread is not None and not self._loop.is_closed():
            self._loop.call_soon_threadsafe(self._stopped.set)
            self._thread.join(timeout_s)

    def call(self, fn: Callable[[], T], timeout_s: float = 5.0) -> T:
        """Run ``fn()`` on the controller's loop thread and return its result (test hook)."""
        assert self._loop is not None

        async def wrapper() -> T:
            return fn()

        return asyncio.run_coroutine_threadsafe(wrapper(), self._loop).result(timeout_s)

    # -- fault injection ----------------------------------------------------------------------

    def drop_client(self) -> None:
        """Abort the current RAPID connection (thread-safe)."""
        assert self.server is not None
        self.call(self.server.drop_client)

    def set_silent(self, silent: bool) -> None:
        """Stop (or resume) answering anything on the RAPID connection (thread-safe)."""
        assert self.server is not None
        server = self.server

        def apply() -> None:
            server.silent = silent

        self.call(apply)

    def set_motors(self, on: bool) -> None:
        """Switch the motors on or off (thread-safe)."""
        with self.robot.lock:
            self.robot.motors_on = on

    @property
    def gripper_hold(self) -> bool:
        """The gripper's vacuum output as GRIP last set it (True: on, holding; thread-safe)."""
        return self.robot.gripper_hold

    def cut_egm_stream(self) -> None:
        """The network or the controller's EGM dies mid-stream: no more datagrams, RAPID still streams (thread-safe)."""
        if self.egm is not None:
            self.egm.stream.cut()

    @property
    def egm_stream_stats(self) -> EgmStreamStats | None:
        """The running or last position stream's statistics (None: none yet)."""
        return None if self.egm is None else self.egm.stream.stats

    @property
    def last_egm_stats(self) -> EgmSessionStats | None:
        """The statistics of the last EGM session that ended (None: none yet)."""
        return None if self.egm is None else self.egm.last_stats
