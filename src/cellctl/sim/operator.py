"""The simulated commissioning engineer, and the twin's witness for calibration datasets.

:class:`SimulatedOperator` answers a commissioning job's prompts as an engineer's hands would act
on a real cell, only on the twin: it clamps the car body at its nominal place, sticks a
checkerboard on the wall where asked (and reports its printed square size), takes it off, and
guides the glass into the opening with a hand-guiding error. Guided moves go through ``jog``
(the ABB fake's jog or the twin's arm), so the job reads them through the Robot port.
:class:`TwinWitness` adds the twin's truth to a dataset's manifest (``twin_truth``), for the
report only. :meth:`cellctl.sim.rig.SimRig.add_operator` builds both.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable
from typing import Any

import numpy as np

from cellctl.commissioning.prompts import Answer, Prompt, PromptKind
from cellctl.config.sim import SimConfig
from cellctl.geometry.pose import Pose, make_pose
from cellctl.geometry.rotation import axis_angle_to_matrix
from cellctl.sim.camera_device import SimCamera
from cellctl.sim.cell import SimCell
from cellctl.sim.streams import rng_stream
from cellctl.sim.targets import Checkerboard, PlacedTarget, place_on_world_plane
from cellctl.sim.world import nominal_world

log = logging.getLogger(__name__)

OPERATOR = "calibration.operator"
ACTOR = "simulated operator"
_ACTIONS = frozenset({PromptKind.CAR_BODY, PromptKind.PLACE_BOARD, PromptKind.REMOVE_BOARD, PromptKind.GUIDE_INSTALL, PromptKind.RETREAT})

Jog = Callable[[Pose], None]
AnswerFn = Callable[[int, int, Answer], Awaitable[object]]


class SimulatedOperator:
    """Acts on the twin for each prompt and answers it (see the module docstring).

    Args:
        cell: the twin.
        config: the twin's configuration (``operator`` says which prompts it answers).
        targets: the calibration targets the twin's camera sees (this list is changed in place).
        jog: moves the robot to a belief pose as a jog or lead-through would.
        recipe: a recipe's twin settings by its name, for a prompt that names the recipe of the car body.
    """

    def __init__(
        self, cell: SimCell, config: SimConfig, targets: list[PlacedTarget], jog: Jog,
        *, recipe: Callable[[str], SimConfig] | None = None,
    ) -> None:
        self.cell = cell
        self.recipe = recipe  # a recipe's twin settings, by name (None: one type of car body)
        self.config = config
        self.targets = targets
        self.jog = jog
        self.answers = config.operator.answers
        self._rng = rng_stream(cell.seed, OPERATOR)
        self._answer: AnswerFn | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self.last_board: PlacedTarget | None = None

    def attach(self, watch: Callable[[Callable[[Prompt], None]], object], answer: AnswerFn) -> None:
        """Listen to new prompts (``watch``) and answer them through ``answer(job_id, prompt_id, Answer)``."""
        self._answer = answer
        watch(self._on_prompt)

    def _on_prompt(self, prompt: Prompt) -> None:
        if self.answers == "none" or (self.answers == "actions" and prompt.kind not in _ACTIONS):
            return
        task = asyncio.get_running_loop().create_task(self._handle(prompt))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _handle(self, prompt: Prompt) -> None:
        delay = self.config.operator.answer_delay_s
        await asyncio.sleep(delay)
        try:
            value = self.act(prompt)
        except Exception as err:  # noqa: BLE001 - a failed act is reported as a cancel with the reason
            log.exception("simulated operator could not do '%s'", prompt.kind.value)
            answer = Answer("cancel", None, f"{ACTOR} ({type(err).__name__}: {err})", "sim")
        else:
            answer = Answer("confirm" if value is None else "value", value, ACTOR, "sim")
        if self._answer is not None:
            try:
                await self._answer(prompt.job_id, prompt.id, answer)
            except Exception as err:  # noqa: BLE001 - answered meanwhile by someone else, or the job ended
                log.info("simulated operator: prompt %d not answered (%s)", prompt.id, err)

    def act(self, prompt: Prompt) -> float | None:
        """Do in the twin what the prompt asks; returns the value to answer with, if any."""
        d = prompt.details
        if prompt.kind is PromptKind.CAR_BODY:
            if self.recipe is not None and isinstance(d.get("recipe"), str):
                self.cell.build_for(self.recipe(d["recipe"]))  # the reference body of the recipe asked for
            if d.get("nominal", False):
                self.cell.place_car_body(nominal_world(self.cell.world_config))
            return None
        if prompt.kind is PromptKind.PLACE_BOARD:
            b = d["board"]
            board = Checkerboard(inner_corners=tuple(b["inner_corners"]), square_mm=float(b["square_mm"]),  # type: ignore[arg-type]
                                 border_mm=float(b.get("border_mm", 10.0)))  # fmt: skip
            placed = PlacedTarget(board, place_on_world_plane(self.cell.world().T_B_T, tuple(d["at_mm"])))  # type: ignore[arg-type]
            self.targets[:] = [placed]
            self.last_board = placed
            return float(b["square_mm"])
        if prompt.kind is PromptKind.REMOVE_BOARD:
            self.targets.clear()
            return None
        if prompt.kind is PromptKind.GUIDE_INSTALL:
            self.jog(self.guided_install_pose())
            return None
        if prompt.kind is PromptKind.RETREAT:
            clear = d.get("clear_pose")
            if clear is not None:
                from cellctl.geometry.pose import pose_from_xyz_fixed

                gx, gy, gz = np.radians(clear["xyz_fixed_deg"])
                self.jog(pose_from_xyz_fixed(clear["position_mm"], gz, gy, gx))
            return None
        return None  # CONFIRM_START: nothing to do in the cell

    def guided_install_pose(self) -> Pose:
        """Where an operator leaves the flange after guiding the glass in: the exact install moved by a hand-guiding error.

        The exact install is what a perfect controller would command (:meth:`SimCell.install_command`);
        the error is drawn per axis in the glass corner frame.
        """
        op = self.config.operator
        exact = self.cell.install_command()
        z = self._rng.normal(size=6)
        err = make_pose(axis_angle_to_matrix(np.deg2rad(op.hand_guiding_orientation_deg) * z[3:]), op.hand_guiding_position_mm * z[:3])
        T_H_G = self.cell.T_H_G
        return exact @ T_H_G @ err @ np.linalg.inv(T_H_G)

    async def close(self) -> None:
        for t in list(self._tasks):
            t.cancel()


class TwinWitness:
    """The twin's truth about what a calibration dataset measured (written beside the data, never computed from)."""

    def __init__(self, cell: SimCell, config: SimConfig, operator: SimulatedOperator, camera: SimCamera | None = None) -> None:
        self.cell = cell
        self.config = config
        self.operator = operator
        self.camera = camera  # the twin's camera, which keeps the true pose of its last frame

    def truth(self, kind: str, facts: dict[str, Any]) -> dict[str, Any] | None:
        cell = self.cell
        if kind == "board_views":
            i = self.config.camera.intrinsics
            out: dict[str, Any] = {
                "intrinsics": {"fx": i.fx, "fy": i.fy, "cx": i.cx, "cy": i.cy, "dist": list(i.dist_coeffs())},
                "T_H_C": cell.T_H_C.tolist(),
            }
            if self.operator.last_board is not None:
                out["T_B_P"] = self.operator.last_board.T_B_P.tolist()
            return out
        if kind == "laser_plane":
            return {"r": cell.laser_model.r.tolist(), "l": cell.laser_model.l.tolist()}
        if kind == "teaching":
            out = {"T_B_T": cell.world().T_B_T.tolist()}
            if self.camera is not None and self.camera.last_pose is not None:  # the template is the job's last frame
                out["C_Pos_0_true"] = (self.camera.last_pose @ np.linalg.inv(cell.T_H_C)).tolist()
            if "g_Pos_0" in facts:
                true_flange = cell.robot_model.deform(np.asarray(facts["g_Pos_0"], dtype=float))
                out["g_Pos_0_install_error"] = cell.truth().score(true_flange).as_dict()
            return out
        if kind == "verify":
            return {"T_H_C": cell.T_H_C.tolist(), "r": cell.laser_model.r.tolist(), "l": cell.laser_model.l.tolist()}
        return None
