"""The cell assembled around its three devices: store, state machine, alarms, orchestrator, jobs.

The composition roots build the devices (:mod:`cellctl.service.hardware` from the real drivers,
:mod:`cellctl.service.simulated` with the twin behind them) and hand them to
:func:`assemble_service`; nothing here imports a driver or the twin. The returned
:class:`Service`'s ``start`` recovers the store and starts the orchestrator, the device
watchdog, the commissioning jobs and the PLC server; ``serve`` runs the HTTP server beside them.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import sys
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cellctl.calibration.calibration_set import CalibrationStore, store_root
from cellctl.calibration.source import CalibrationSetSource
from cellctl.cell.alarms import AlarmManager
from cellctl.cell.cycle_values import CellDevices
from cellctl.cell.events import EventHub
from cellctl.cell.orchestrator import CellOrchestrator
from cellctl.cell.packml import PackMLMachine
from cellctl.cell.robots import TrackedRobot
from cellctl.cell.sources import CalibrationSource, SimTruth
from cellctl.cell.watchdog import DeviceWatchdog, WatchdogSettings
from cellctl.commissioning.context import Witness
from cellctl.commissioning.jobs import JobManager
from cellctl.config.schema import CellConfig
from cellctl.domain import PackMLState, UnitMode
from cellctl.folders import calibration_folder_problem
from cellctl.listen import port_problem
from cellctl.ports import Camera, DisplacementSensor, Robot
from cellctl.service.errors import ServiceClockBehind, ServiceConfigError, ServiceError
from cellctl.service.plc_link import PlcCellLink
from cellctl.service.retention import StorageRetention  # issue 15 item 7
from cellctl.service.store_lock import StoreInUse, StoreLock
from cellctl.store import AsyncCellStore
from cellctl.store.connection import StoreDamaged, StorePathError, check_store_path, make_store_folder
from cellctl.store.records import SchemaTooNew

log = logging.getLogger(__name__)

Closer = Callable[[], Awaitable[None]]
STOP_STEP_TIMEOUT_S = 10.0
JOB_END_BEFORE_STREAMS_S = 2.5
"""On SIGINT/SIGTERM a running job gets this long (s) to end before the event streams close (the HTTP server
closes them itself 3 s after the signal, cellctl.service.http.GRACEFUL_SHUTDOWN_S)."""
CYCLE_END_AT_EXIT_S = 2.5
"""On SIGINT/SIGTERM a running cycle gets this long (s) to stop and be recorded (before a running job is cancelled)."""


def closer_steps(closers: list[Closer]) -> list[tuple[str, Closer]]:
    """``closers`` as named stop steps, the last added first (a device before what it was built on)."""
    return [(getattr(close, "__qualname__", "device"), close) for close in reversed(closers)]


async def stop_in_turn(steps: list[tuple[str, Closer]]) -> None:
    """Run each step within ``STOP_STEP_TIMEOUT_S``; one that hangs or fails is logged and the rest still run."""
    for name, step in steps:
        try:
            await asyncio.wait_for(step(), STOP_STEP_TIMEOUT_S)
        except asyncio.TimeoutError:
            log.error("stopping %s took over %.0f s; went on without it", name, STOP_STEP_TIMEOUT_S)
        except Exception:  # a failing part must not keep the others running; logged with its trace
            log.exception("stopping %s failed", name)


@dataclass
class Service:
    """Everything the running cell is made of."""

    config: CellConfig
    store: AsyncCellStore
    orchestrator: CellOrchestrator
    jobs: JobManager
    plc_link: PlcCellLink
    workdir: Path
    closers: list[Closer] = field(default_factory=list)
    plc_server: object | None = None
    opcua_server: Any = None
    after_start: list[Callable[["Service"], Awaitable[None]]] = field(default_factory=list)
    commissioning: asyncio.Task[None] | None = None
    extras: dict[str, object] = field(default_factory=dict)  # what a root adds (the simulated cell: its twin and operator)
    stopped: bool = False
    store_lock: StoreLock | None = None  # held from before the store opens until it has closed
    _loop: asyncio.AbstractEventLoop | None = field(default=None, repr=False)
    _exit_signalled: bool = field(default=False, repr=False)
    _ending: asyncio.Task[None] | None = field(default=None, repr=False)

    async def start(self) -> None:
        await self.orchestrator.start()
        await self.jobs.start()
        if self.config.plc.enabled:
            from cellctl.plc.server import PlcServer

            server = PlcServer(self.config.plc, self.plc_link)
            try:
                await server.start(watch_heartbeat=False)  # its first window opens once the service is up
            except OSError as err:
                await self.stop()  # devices, jobs and the store too: a failed start leaves nothing running
                raise ServiceError(f"the PLC Modbus server cannot start: {err}") from None
            self.plc_server = server
            self.orchestrator.note_link("plc", "waiting")  # until the PLC's first heartbeat
            log.info("PLC Modbus TCP server on %s:%d", self.config.plc.host, server.port)
        if self.config.opcua.enabled:
            from cellctl.opcua.security import CertificateNotValidYet, ServerCertificateError
            from cellctl.opcua.server import CellOpcUaServer, OpcUaPortInUse, OpcUaStartError
            from cellctl.service.opcua_link import OpcUaCellLink

            recipes = tuple(self.config.process.recipe_names().values())
            opcua = CellOpcUaServer(self.config.opcua, OpcUaCellLink(self.orchestrator, self.config.cell_id, recipes),
                                    root=self.workdir)  # fmt: skip
            try:
                await opcua.start()
            except (OpcUaStartError, ServerCertificateError, OSError) as err:  # each names its setting and fix
                await opcua.stop()
                await self.stop()
                can_clear = isinstance(err, (OSError, OpcUaPortInUse))  # a port in use; the rest is the configuration
                kind = ServiceError if can_clear else ServiceConfigError
                kind = ServiceClockBehind if isinstance(err, CertificateNotValidYet) else kind  # a restart cures it
                raise kind(f"the OPC UA server cannot start: {err}") from None
            self.opcua_server = opcua
            log.info("OPC UA server on %s", opcua.endpoint)
        for hook in self.after_start:
            await hook(self)
        if self.plc_server is not None:  # the PLC's heartbeat counts from now, not from before the OPC UA start
            self.plc_server.watch_heartbeat()  # type: ignore[attr-defined]

    async def ready_for_production(self, timeout_s: float | None = None) -> None:
        """Wait for a commissioning the root started on its own (the simulated cell's) to finish; raises its failure."""
        if self.commissioning is not None:
            await asyncio.wait_for(asyncio.shield(self.commissioning), timeout_s)

    async def stop(self) -> None:
        """Stop everything; each part gets ``STOP_STEP_TIMEOUT_S``, so a stuck one cannot hang the rest. Once."""
        if self.stopped:
            return
        self.stopped = True
        steps: list[tuple[str, Closer]] = []
        if self.commissioning is not None and not self.commissioning.done():
            self.commissioning.cancel()
        steps.append(("commissioning jobs", self.jobs.stop))
        if self.plc_server is not None:
            steps.append(("PLC server", self.plc_server.stop))  # type: ignore[attr-defined]
        if self.opcua_server is not None:
            steps.append(("OPC UA server", self.opcua_server.stop))
        steps += [("PLC link", self.plc_link.close), ("orchestrator", self.orchestrator.stop)]
        steps += closer_steps(self.closers)
        steps.append(("store", self.store.close))
        await stop_in_turn(steps)
        if self.store_lock is not None:
            self.store_lock.release()

    async def serve(self, *, ready: asyncio.Event | None = None, demo_cycles: int = 0) -> int | None:
        """Run the REST API and dashboard until the process is told to stop (SIGINT or SIGTERM, alike).

        ``demo_cycles`` > 0 first brings the cell to Execute and installs that many windows.
        Returns the signal that ended it (None if the server ended otherwise); the service is
        stopped either way (devices, a running job cancelled, the store closed).
        """
        from cellctl.api.app import create_app
        from cellctl.config.api import NotValidYet
        from cellctl.service.http import make_server

        api = self.config.api.rooted(self.workdir)  # token files and TLS files taken from the workdir
        app = create_app(self.orchestrator, api, self.jobs)
        self._loop = asyncio.get_running_loop()
        tls = (api.tls_cert, api.tls_key) if api.tls_cert is not None and api.tls_key is not None else None
        server = make_server(app, api.host, api.port, self._on_exit_signal, tls=tls)
        demo: asyncio.Task[None] | None = None
        try:
            if problems := api.tls_problems(self.workdir):  # before anything starts: uvicorn would fail only once up
                behind = all(isinstance(p, NotValidYet) for p in problems)  # the clock stands behind: a restart cures it
                kind = ServiceClockBehind if behind else ServiceConfigError
                raise kind("the REST API cannot serve HTTPS: " + "; ".join(problems))
            if self.config.mode == "hardware" and (warning := api.plain_http_warning()) is not None:
                log.warning("%s", warning)
            await self.start()
            task = asyncio.create_task(server.serve())
            while not server.started and not task.done():
                await asyncio.sleep(0.05)
            if not server.started:
                with contextlib.suppress(BaseException):
                    await task
                raise ServiceError(self._api_listen_problem())
            print(f"cellctl serving on {self.api_url} (mode {self.config.mode}); Ctrl-C stops", flush=True)
            if self.opcua_server is not None:
                print(f"OPC UA on {self.opcua_server.endpoint} (namespace urn:cellctl:opcua, docs/opcua_nodeset.md)", flush=True)
            if ready is not None:
                ready.set()
            if demo_cycles and not task.done():
                demo = asyncio.create_task(self._demo(demo_cycles))
            await task
            return server.signal_received
        finally:
            if demo is not None and not demo.done():
                demo.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await demo
            if self._ending is not None:
                with contextlib.suppress(Exception):
                    await self._ending
            await self.stop()

    def _api_listen_problem(self) -> str:
        """Why uvicorn could not listen (it logs the error and exits): the cause found again by a trial bind."""
        host, port = self.config.api.host, self.config.api.port
        why = port_problem("[api] port", host, port) or "check [api] host and [api] port (uvicorn's log above says why)"
        return f"the REST API cannot listen on {host}:{port}: {why}"

    @property
    def api_url(self) -> str:
        """Where the REST API and dashboard are served (https with api.tls_cert)."""
        api = self.config.api
        return f"{'https' if api.tls_cert is not None else 'http'}://{api.host}:{api.port}/"

    def _on_exit_signal(self) -> None:
        """SIGINT/SIGTERM (called in the signal handler): a running cycle is stopped and recorded (the robot stopped,
        the waiting caller and the PLC answered) and a running job cancelled first, so that whoever follows them reads
        their end on the event stream; then the streams end with ``shutdown``. A second signal ends them at once."""
        if self._exit_signalled or self._loop is None:
            self.orchestrator.events.close()
            return
        self._exit_signalled = True
        self._loop.call_soon_threadsafe(self._begin_ending)

    def _begin_ending(self) -> None:
        self._ending = asyncio.ensure_future(self._end_work_then_close_streams())

    async def _end_work_then_close_streams(self) -> None:
        try:
            await asyncio.wait_for(self.orchestrator.end_for_shutdown("the service is stopping"), CYCLE_END_AT_EXIT_S)
        except Exception as err:  # noqa: BLE001 - stop() cancels it again; the next start marks it interrupted
            log.warning("the running cycle did not end before the service stopped: %r", err)
        try:
            run = self.jobs.running()
            if run is not None:
                await asyncio.wait_for(self.jobs.cancel(run.id, actor="system", source="service", reason="the service is stopping"),
                                       JOB_END_BEFORE_STREAMS_S)  # fmt: skip
        except Exception as err:  # noqa: BLE001 - the streams end whatever the job did; stop() cancels it again
            log.warning("the running job did not end before the event streams closed: %r", err)
        finally:
            self.orchestrator.events.close()

    async def _demo(self, cycles: int) -> None:
        from cellctl.service.demo import run_demo

        await run_demo(self, cycles, sys.stdout)
        print(f"serving on {self.api_url} ; Ctrl-C stops", flush=True)


async def assemble_service(
    config: CellConfig,
    *,
    laser: DisplacementSensor,
    camera: Camera,
    robot: Robot,
    workdir: Path | None = None,
    calibration: CalibrationSource | None = None,
    truth: SimTruth | None = None,
    witness: Witness | None = None,
    clock: Callable[[], float] = time.monotonic,
) -> Service:
    """Build (not start) the cell around its devices. Relative paths are taken from ``workdir``.

    ``calibration`` defaults to the versioned calibration set of ``calibration.directory``;
    ``truth``, ``witness`` and the ``clock`` of the twin's time line are the simulated cell's.
    """
    root = (workdir or Path.cwd()).resolve()
    robot = TrackedRobot(robot)
    if (problem := calibration_folder_problem(config.calibration.directory, root)) is not None:
        raise ServiceConfigError(problem)  # else the first calibration would fail long after a start that said nothing
    cal_store = CalibrationStore(store_root(config.calibration.directory, root))
    source = calibration if calibration is not None else CalibrationSetSource(cal_store, config)
    db_path = Path(config.store.path)
    db_path = db_path if db_path.is_absolute() else root / db_path
    lock = StoreLock(db_path)
    try:
        make_store_folder(db_path)  # a file in the way, or no right to create it
        check_store_path(db_path)  # a folder at the path, or a folder the service may not write in
        lock.acquire()  # before the store is opened: startup's recovery must never touch a running cell's cycles
        store = await AsyncCellStore.open(db_path, synchronous=config.store.synchronous, busy_timeout_s=config.store.busy_timeout_s)
    except StoreInUse as err:
        raise ServiceError(str(err)) from None
    except BaseException as err:
        lock.release()
        if isinstance(err, StorePathError | SchemaTooNew) and not isinstance(err, StoreDamaged):  # names the file, the fix
            raise ServiceConfigError(str(err)) from None  # a restart cannot help: exit 2
        raise
    if store.upgrade is not None:
        up = store.upgrade
        log.warning("%s", up.summary())
        await store.append_audit(actor="system", source="store", action="store.migrated", params={
            "from_schema": up.from_version, "to_schema": up.to_version, "kept_copy": str(up.kept_copy)})
    pk = config.packml
    machine = PackMLMachine(
        initial_state=PackMLState[pk.initial_state.upper()],
        initial_mode=UnitMode[pk.initial_mode.upper()],
        mode_change_states={PackMLState[s.upper()] for s in pk.mode_change_states},
    )
    alarms = AlarmManager(machine, robot_moving=lambda: robot.moving, history=config.alarms.history)
    alarms.install()
    if isinstance(source, CalibrationSetSource):  # issue 15 item 6: a damaged set file raises its alarm once
        source.attach_alarms(alarms)
        source.attach_audit(store)
    watchdog = DeviceWatchdog(alarms, defaults=WatchdogSettings(**config.alarms.watchdog.model_dump()))
    watchdog.add("laser", laser)
    watchdog.add("camera", camera)
    watchdog.add("robot", robot)
    events = EventHub()
    devices = CellDevices(laser, camera, robot, clock)
    orch = CellOrchestrator(
        config=config,
        devices=devices,
        calibration=source,
        store=store,
        machine=machine,
        alarms=alarms,
        watchdog=watchdog,
        events=events,
        image_dir=db_path.parent / "images",
        truth=truth,
    )
    jobs = JobManager(
        config=config, devices=devices, calibration_store=cal_store, store=store, machine=machine, alarms=alarms,
        events=events, witness=witness, call_timeout_s=config.devices.call_timeout_s,
    )  # fmt: skip
    orch.add_status("job", jobs.status)
    link = PlcCellLink(orch, config.process.recipe_names(), heartbeat_alarm=config.plc.heartbeat_alarm)
    service = Service(config, store, orch, jobs, link, root, store_lock=lock)
    # -- issue 15 item 7: retention, disk-space alarms and the /status "storage" figures (cellctl.service.retention)
    retention = StorageRetention(
        config.store.retention, store, alarms, image_dir=orch.image_dir, db_path=db_path, events=events,
        cycle_step=lambda: machine.cycle_step, mqtt_results=config.mqtt.enabled,
    )  # fmt: skip
    orch.add_status("storage", retention.status)
    service.extras["retention"] = retention
    service.after_start.append(lambda _svc: retention.start())
    service.closers.append(retention.stop)  # runs before the store closes
    # -- end issue 15 item 7
    # -- issue 18 item 3: MQTT publication to the plant's broker (cellctl.mqtt; docs/mqtt.md)
    if config.mqtt.enabled:
        from cellctl.mqtt import MqttPublication, MqttSetupError
        from cellctl.mqtt.publication import MqttCertificateNotValidYet

        mqtt = MqttPublication(config.mqtt, orch, workdir=root)
        orch.add_status("mqtt", mqtt.status)
        service.extras["mqtt"] = mqtt

        async def start_mqtt(_svc: Service) -> None:
            try:
                await mqtt.start()
            except MqttSetupError as err:
                kind = ServiceClockBehind if isinstance(err, MqttCertificateNotValidYet) else ServiceConfigError
                raise kind(f"MQTT publication cannot start: {err}") from None

        service.after_start.append(start_mqtt)
        service.closers.append(mqtt.stop)  # after the orchestrator, before the store closes
    # -- end issue 18 item 3
    return service
