"""The simulated cell's composition root: the twin behind the ports, and its commissioning engineer.

The devices of ``[devices]`` are the twin's own (``kind = "sim"``), or the real LK-G and ABB
drivers talking to their protocol fakes whose physics is the twin (``sim_keyence_lkg``,
``sim_abb``); the rest of the cell is assembled exactly as on hardware. The twin (one
:class:`~cellctl.sim.rig.SimRig`) also brings its operator, who answers commissioning prompts by
acting on it; with ``calibration.auto_calibrate_in_sim`` the cell commissions itself at start
through the same jobs an engineer would run. Only here (and in the benchmarks) is
:mod:`cellctl.sim` imported.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

from cellctl.commissioning.auto import commission_missing, parts_needed
from cellctl.config.devices import SimAbbDevice, SimKeyenceLkgDevice
from cellctl.config.schema import TWIN_KINDS, CellConfig
from cellctl.geometry.pose import Pose
from cellctl.ports import Camera, DisplacementSensor, Robot
from cellctl.service.compose import Closer, Service, ServiceConfigError, ServiceError, assemble_service, closer_steps, stop_in_turn
from cellctl.sim.operator import ACTOR
from cellctl.sim.rig import SimRig, recipe_twins

log = logging.getLogger(__name__)


def _devices(
    config: CellConfig, rig: SimRig, closers: list[Closer], fakes: dict[str, object]
) -> tuple[DisplacementSensor, Camera, Robot, Callable[[Pose], None]]:
    """The twin's devices, or the real LK-G and ABB drivers on their protocol fakes (``sim_*``; a real kind is
    refused at load in mode "sim")."""
    dev = config.devices
    laser: DisplacementSensor = rig.laser
    robot: Robot = rig.robot
    if isinstance(dev.laser, SimKeyenceLkgDevice):
        from cellctl.service.sim_fakes import lkg_on_fake

        laser, close = lkg_on_fake(rig.cell, dev.laser, fakes)
        closers.append(close)
    jog: Callable[[Pose], None] = rig.cell.execute
    if isinstance(dev.robot, SimAbbDevice):
        from cellctl.service.sim_fakes import abb_on_fake

        robot, close, jog = abb_on_fake(rig.cell, dev.robot, fakes)
        closers.append(close)
    return laser, rig.camera, robot, jog


def fakes_out_of_time(config: CellConfig) -> str | None:
    """Why the drivers' fakes cannot serve reading on the move at this ``sim.time_scale``, or None.

    The LK-G fake stores and the ABB fake streams EGM feedback on the host's clock, so a sweep
    through them needs the twin to move in real time.
    """
    fakes = ["laser"] if isinstance(config.devices.laser, SimKeyenceLkgDevice) else []
    fakes += ["robot"] if isinstance(config.devices.robot, SimAbbDevice) and config.devices.robot.egm else []
    moving = [r.name for r in config.process.recipes if config.for_recipe(r.name).process.align.mode == "on_the_fly"]
    if not fakes or not (moving or config.process.align.mode == "on_the_fly") or config.sim.time_scale == 1.0:
        return None
    return (
        f'process.align.mode = "on_the_fly" (recipes: {", ".join(moving) or "none"}) with devices {fakes} on their '
        f"protocol fakes, which store and stream in real time, needs sim.time_scale = 1.0 (it is "
        f'{config.sim.time_scale:g}); or give those devices kind = "sim" (the twin\'s own keep the twin\'s time)'
    )


async def _auto_commission(service: Service) -> None:
    needed = parts_needed(service.jobs)
    if not needed:
        return
    log.info("simulated cell: commissioning %s through the service's jobs (the simulated operator answers)", ", ".join(map(str, needed)))
    await commission_missing(service.jobs, service.orchestrator.machine, actor=ACTOR, source="sim")


async def build_sim_service(config: CellConfig, *, workdir: Path | None = None, seed: int | None = None) -> Service:
    """The simulated cell (``mode = "sim"``): the twin, its devices, its operator; ``seed`` overrides ``sim.seed``."""
    if config.mode != "sim":
        raise ServiceError('the simulated cell root builds mode = "sim" only; a real cell uses the hardware root')
    real = [name for name, kinds in TWIN_KINDS.items() if getattr(config.devices, name).kind not in kinds]
    if real:  # refused at load; a configuration copied past validation must not get the twin's devices instead
        raise ServiceConfigError(f"devices {real} are real devices: the simulated cell drives the twin's kinds only "
                           f'({TWIN_KINDS}); set mode = "hardware" for a real cell')
    if (why := fakes_out_of_time(config)) is not None:
        raise ServiceConfigError(why)
    import asyncio

    rig = SimRig(config.sim, seed=seed, recipes=recipe_twins(config))
    closers: list[Closer] = []
    fakes: dict[str, object] = {}
    try:
        laser, camera, robot, jog = _devices(config, rig, closers, fakes)
        calibration = None
        if config.calibration.source == "oracle":
            from cellctl.sim.oracle import OracleCalibrationSource

            calibration = OracleCalibrationSource(rig, config)
        operator, witness = rig.add_operator(jog, twin_camera=camera is rig.camera)
        service = await assemble_service(
            config, laser=laser, camera=camera, robot=robot, workdir=workdir, calibration=calibration, truth=rig,
            witness=witness, clock=rig.cell.timeline.now,
        )  # fmt: skip
    except BaseException:  # a refused start (store, ports, calibration) leaves no fake's terminal or thread behind
        await stop_in_turn(closer_steps([*closers, rig.close]))  # as the service's stop would have
        raise
    operator.attach(service.jobs.desk.watch, service.jobs.answer)
    service.closers.extend([*closers, rig.close])  # the twin's devices, then its operator, are closed first
    service.extras.update(twin=rig, operator=operator, fakes=fakes)
    if config.calibration.source == "set" and config.calibration.auto_calibrate_in_sim:

        async def start_commissioning(svc: Service) -> None:
            svc.commissioning = asyncio.create_task(_auto_commission(svc))

        service.after_start.append(start_commissioning)
    return service
