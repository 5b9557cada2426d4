"""Build the whole cell from its configuration: the composition root (the only place drivers are imported).

:func:`build_service` returns a :class:`Service` whose ``start`` recovers the store and starts the
orchestrator, the device watchdog and the PLC server; ``serve`` runs the HTTP server beside them.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import sys
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path

from cellctl.cell.alarms import AlarmManager
from cellctl.cell.cycle import CellDevices
from cellctl.cell.events import EventHub
from cellctl.cell.orchestrator import CalibrationSource, CellOrchestrator, TrackedRobot
from cellctl.cell.packml import PackMLMachine
from cellctl.cell.tags import PackMLState, UnitMode
from cellctl.cell.watchdog import DeviceWatchdog, WatchdogSettings
from cellctl.config.schema import CellConfig
from cellctl.ports import Camera, DisplacementSensor, Robot
from cellctl.service.plc_link import PlcCellLink
from cellctl.store import AsyncCellStore

log = logging.getLogger(__name__)

Closer = Callable[[], Awaitable[None]]
STOP_STEP_TIMEOUT_S = 10.0


class ServiceError(RuntimeError):
    """The service cannot be built from this configuration; the message says what to change."""


@dataclass
class Service:
    """Everything the running cell is made of."""

    config: CellConfig
    store: AsyncCellStore
    orchestrator: CellOrchestrator
    plc_link: PlcCellLink
    workdir: Path
    closers: list[Closer] = field(default_factory=list)
    plc_server: object | None = None

    async def start(self) -> None:
        await self.orchestrator.start()
        if self.config.plc.enabled:
            from cellctl.plc.server import PlcServer

            server = PlcServer(self.config.plc, self.plc_link)
            try:
                await server.start()
            except OSError as err:
                await self.orchestrator.stop()
                raise ServiceError(
                    f"the PLC Modbus server cannot listen on {self.config.plc.host}:{self.config.plc.port} ({err}); "
                    "is another cellctl running? change [plc] port or stop the other one"
                ) from None
            self.plc_server = server
            self.orchestrator.note_link("plc", "waiting")  # until the PLC's first heartbeat
            log.info("PLC Modbus TCP server on %s:%d", self.config.plc.host, server.port)

    async def stop(self) -> None:
        """Stop everything; each part gets ``STOP_STEP_TIMEOUT_S``, so a stuck one cannot hang the rest."""
        steps: list[tuple[str, Closer]] = []
        if self.plc_server is not None:
            steps.append(("PLC server", self.plc_server.stop))  # type: ignore[attr-defined]
        steps += [("PLC link", self.plc_link.close), ("orchestrator", self.orchestrator.stop)]
        steps += [(getattr(close, "__qualname__", "device"), close) for close in reversed(self.closers)]
        steps.append(("store", self.store.close))
        for name, step in steps:
            try:
                await asyncio.wait_for(step(), STOP_STEP_TIMEOUT_S)
            except asyncio.TimeoutError:
                log.error("stopping %s took over %.0f s; went on without it", name, STOP_STEP_TIMEOUT_S)
            except Exception:  # a failing part must not keep the others running; logged with its trace
                log.exception("stopping %s failed", name)

    async def serve(self, *, ready: asyncio.Event | None = None, demo_cycles: int = 0) -> None:
        """Run the REST API and dashboard until the process is told to stop (SIGINT/SIGTERM).

        ``demo_cycles`` > 0 first brings the cell to Execute and installs that many windows.
        """
        import uvicorn

        from cellctl.api.app import create_app

        app = create_app(self.orchestrator, self.config.api)
        server = uvicorn.Server(
            uvicorn.Config(app, host=self.config.api.host, port=self.config.api.port, log_level="warning", lifespan="off")
        )
        await self.start()
        try:
            task = asyncio.create_task(server.serve())
            while not server.started and not task.done():
                await asyncio.sleep(0.05)
            if not server.started:
                with contextlib.suppress(BaseException):
                    await task
                raise ServiceError(
                    f"the REST API cannot listen on {self.config.api.host}:{self.config.api.port}; "
                    "is another cellctl running? change [api] port or stop the other one"
                )
            if ready is not None:
                ready.set()
            if demo_cycles and not task.done():
                from cellctl.service.demo import run_demo

                await run_demo(self, demo_cycles, sys.stdout)
                print(f"serving on http://{self.config.api.host}:{self.config.api.port}/ ; Ctrl-C stops", flush=True)
            await task
        finally:
            await self.stop()


def _sim_rig(config: CellConfig, holder: dict[str, object]) -> object:
    if "rig" not in holder:
        if config.mode != "sim":
            raise ServiceError("a device of kind 'sim' needs mode = \"sim\" (the twin is only built in the simulated cell)")
        from cellctl.sim.rig import SimRig

        holder["rig"] = SimRig(config.sim)
    return holder["rig"]


def _build_devices(
    config: CellConfig, holder: dict[str, object], closers: list[Closer]
) -> tuple[DisplacementSensor, Camera, Robot]:
    """The three devices per [devices]. Closers of drivers (and their fakes) go to ``closers``; the
    twin's own devices are closed with the rig."""
    dev = config.devices
    laser: DisplacementSensor
    camera: Camera
    robot: Robot
    if dev.laser.kind == "sim":
        laser = _sim_rig(config, holder).laser  # type: ignore[attr-defined]
    elif dev.laser.kind == "sim_keyence_lkg":
        from cellctl.service.sim_fakes import lkg_on_fake

        laser, close = lkg_on_fake(_sim_rig(config, holder).cell, dev.laser)  # type: ignore[attr-defined]
        closers.append(close)
    else:
        from keyence_lkg import KeyenceLkgSensor

        laser = KeyenceLkgSensor.from_config(dev.laser.model_dump())
        closers.append(laser.close)
    if dev.camera.kind == "sim":
        camera = _sim_rig(config, holder).camera  # type: ignore[attr-defined]
    else:
        from genicam_camera import GenicamCamera

        camera = GenicamCamera.from_config(dev.camera.model_dump())
        closers.append(camera.close)
    if dev.robot.kind == "sim":
        robot = _sim_rig(config, holder).robot  # type: ignore[attr-defined]
    elif dev.robot.kind == "sim_abb":
        from cellctl.service.sim_fakes import abb_on_fake

        robot, close = abb_on_fake(_sim_rig(config, holder).cell, dev.robot)  # type: ignore[attr-defined]
        closers.append(close)
    else:
        from abb_robot import AbbRobot, AbbRobotSettings

        robot = AbbRobot(AbbRobotSettings(**dev.robot.model_dump(exclude={"kind"})))
        closers.append(robot.close)
    return laser, camera, robot


def _calibration_source(config: CellConfig, holder: dict[str, object], workdir: Path) -> CalibrationSource:
    if config.calibration.source == "oracle":
        if "rig" not in holder:
            raise ServiceError(
                "calibration.source = \"oracle\" needs the twin (mode = \"sim\" with at least one sim device); "
                "use source = \"set\" with a calibrated cell"
            )
        from cellctl.sim.oracle import OracleCalibrationSource

        return OracleCalibrationSource(holder["rig"], config)  # type: ignore[arg-type]
    from cellctl.calibration.source import CalibrationSetSource

    return CalibrationSetSource.from_config(config, workdir=workdir)


async def build_service(config: CellConfig, *, workdir: Path | None = None) -> Service:
    """Build (not start) the cell from ``config``. Relative paths are taken from ``workdir``."""
    root = (workdir or Path.cwd()).resolve()
    holder: dict[str, object] = {}
    closers: list[Closer] = []
    laser, camera, robot_port = _build_devices(config, holder, closers)
    robot = TrackedRobot(robot_port)
    calibration = _calibration_source(config, holder, root)
    db_path = Path(config.store.path)
    db_path = db_path if db_path.is_absolute() else root / db_path
    db_path.parent.mkdir(parents=True, exist_ok=True)
    store = await AsyncCellStore.open(db_path, synchronous=config.store.synchronous, busy_timeout_s=config.store.busy_timeout_s)
    pk = config.packml
    machine = PackMLMachine(
        initial_state=PackMLState[pk.initial_state.upper()],
        initial_mode=UnitMode[pk.initial_mode.upper()],
        mode_change_states={PackMLState[s.upper()] for s in pk.mode_change_states},
    )
    alarms = AlarmManager(machine, robot_moving=lambda: robot.moving, history=config.alarms.history)
    alarms.install()
    watchdog = DeviceWatchdog(alarms, defaults=WatchdogSettings(**config.alarms.watchdog.model_dump()))
    watchdog.add("laser", laser)
    watchdog.add("camera", camera)
    watchdog.add("robot", robot)
    rig = holder.get("rig")
    orch = CellOrchestrator(
        config=config,
        devices=CellDevices(laser, camera, robot),
        calibration=calibration,
        store=store,
        machine=machine,
        alarms=alarms,
        watchdog=watchdog,
        events=EventHub(),
        image_dir=db_path.parent / "images",
        truth=rig,  # type: ignore[arg-type]
    )
    service = Service(config, store, orch, PlcCellLink(orch, config.process.recipe_names(), heartbeat_alarm=config.plc.heartbeat_alarm), root)
    service.closers.extend(closers)
    if rig is not None:
        service.closers.append(rig.close)  # type: ignore[attr-defined]
    return service
