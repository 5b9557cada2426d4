"""The one assembly of the digital twin: physics, devices behind the ports, operator and witness.

:class:`~cellctl.sim.cell.SimCell` is the twin's physics and truth (car body, robot, laser); the
rig adds the camera renderer, the calibration targets on the wall, the three in-process devices
(``kind = "sim"``), and on request the simulated operator with the witness that writes the truth
beside a dataset. The simulated cell's root, the oracle calibration and the commissioning harness
all build on it; the driver packages' protocol fakes take their physics from ``rig.cell``.
"""

from __future__ import annotations

from collections.abc import Mapping

from cellctl.config.schema import CellConfig
from cellctl.config.sim import SimConfig
from cellctl.domain import InstallDeviation
from cellctl.sim.camera import CameraRenderer
from cellctl.sim.camera_device import SimCamera
from cellctl.sim.cell import SimCell
from cellctl.sim.devices import SimDisplacementSensor, SimRobot
from cellctl.sim.operator import Jog, SimulatedOperator, TwinWitness
from cellctl.sim.streams import rng_stream
from cellctl.sim.targets import PlacedTarget


def recipe_twins(config: CellConfig) -> dict[str, SimConfig]:
    """Each recipe's twin settings (its car body's opening, its glass), by name: ``recipes`` of :class:`SimRig`."""
    return {r.name: config.for_recipe(r.name).sim for r in config.process.recipes}


CAMERA_NOISE = "camera.noise"
TEACH_CAMERA_NOISE = "camera.noise.teach"


class SimRig:
    """The twin with its laser, camera and robot, and (after :meth:`add_operator`) its operator.

    Attributes:
        cell: the twin's physics and truth.
        renderer: the camera's image formation (its ray map is built once, here).
        targets: the calibration targets stuck on the wall now (the camera renders them).
        laser, camera, robot: the devices, implementing the ports.
        teach_rng: the camera noise of the oracle's teaching shots.
        operator, witness: the simulated operator and the twin's witness (None until added).
        recipes: each recipe's twin settings (its opening and glass), by name; a recipe not listed
            is built as ``config`` says.
    """

    def __init__(self, config: SimConfig, *, seed: int | None = None, recipes: Mapping[str, SimConfig] | None = None) -> None:
        self.cell = SimCell(config, seed=seed)
        self.recipes: dict[str, SimConfig] = dict(recipes or {})
        self.renderer = CameraRenderer(config.camera.intrinsics, config.camera.render)
        self.targets: list[PlacedTarget] = []
        self.laser = SimDisplacementSensor(self.cell)
        self.robot = SimRobot(self.cell)
        self.camera = SimCamera(
            self.renderer, self.cell.true_camera_pose, self.cell.world, rng_stream(self.cell.seed, CAMERA_NOISE),
            targets=lambda: tuple(self.targets), glass=self.cell.installed_glass_scene,
            timeline=self.cell.timeline, frame_time_s=config.camera.frame_time_s,
        )
        self.teach_rng = rng_stream(self.cell.seed, TEACH_CAMERA_NOISE)
        self.operator: SimulatedOperator | None = None
        self.witness: TwinWitness | None = None

    def add_operator(
        self, jog: Jog | None = None, *, answer_everything: bool = False, twin_camera: bool = True
    ) -> tuple[SimulatedOperator, TwinWitness]:
        """The simulated operator acting on this twin, and the witness that reports what it did.

        Args:
            jog: moves the robot as a jog or lead-through would (default: the twin's arm directly).
            answer_everything: answer every prompt at once, whatever ``sim.operator`` says.
            twin_camera: the cell's camera is this rig's (the witness then reads its last pose).
        """
        sim = self.cell.config
        acting = sim
        if answer_everything:
            acting = sim.model_copy(update={"operator": sim.operator.model_copy(update={"answers": "all", "answer_delay_s": 0.0})})
        self.operator = SimulatedOperator(
            self.cell, acting, self.targets, self.cell.execute if jog is None else jog, recipe=self.recipe_settings
        )
        self.witness = TwinWitness(self.cell, sim, self.operator, self.camera if twin_camera else None)
        return self.operator, self.witness

    # SimTruth of the orchestrator

    def recipe_settings(self, recipe: str) -> SimConfig:
        """The twin's settings of a car body and glass of ``recipe``."""
        return self.recipes.get(recipe, self.cell.config)

    def new_car_body(self, recipe: str | None = None) -> None:
        """The next car body arrives at a random posture, built for ``recipe`` (None: the same type as the last)."""
        self.cell.new_car_body(None if recipe is None else self.recipe_settings(recipe))

    def install_error(self) -> InstallDeviation:
        """The paper's six figures of the glass: where it was released, else as the flange holds it now."""
        return self.cell.install_error()

    async def close(self) -> None:
        """Close the devices, then stop the operator (if any)."""
        for dev in (self.laser, self.camera, self.robot):
            await dev.close()
        if self.operator is not None:
            await self.operator.close()
