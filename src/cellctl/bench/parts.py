"""The calibration parts of a cell, one at a time swapped for the twin's true value (the budget by part).

A cycle uses, from the calibration set (:class:`~cellctl.cell.cycle_values.CycleCalibration`): the camera
intrinsics (``lens``), the hand-eye transform (``T_H_C``), the laser ray (``laser_r``, ``laser_l``),
the nine-point map (``nine_point``) and what teaching recorded (``taught``: T0, C_Pos_0, g_Pos_0, and
the corner ``template``). They are not independent: teaching measures the shooting pose C_Pos_0 by
a laser alignment (through the laser ray and the hand-eye) and the template through the camera (its
lens), and the nine-point map is measured at C_Pos_0 through the lens. The cycle is relative to
teaching (the camera sees the car body's displacement from where it stood at teaching), so a part's
error that went into teaching cancels in part; swapping the camera, the hand-eye or the laser alone,
with C_Pos_0 and the template left as they were measured through the old part, breaks that and adds
an error neither calibration has. Those three are therefore swapped with their dependent chain:

- **camera**, **hand_eye**, **laser** (upstream): the part set to its true value, then C_Pos_0 and the
  template re-taught with it in a copy of the twin (same seed; the car body at its nominal
  placement, as teaching has it; the laser alignment and the shot each averaged over ``repeats``
  fresh robot moves, as the oracle teaches) and the nine-point map measured perfectly (below) at the
  new C_Pos_0 for the part's lens. Their effect is read against **re-taught**, the same re-teaching
  with all of the cell's own parts, so the re-teaching procedure itself cancels. T0 follows from
  the re-taught shot and wall plane as the teaching job computes it, so each re-taught set is as
  self-consistent as a taught one (a T0 kept from the old shot would add the old shot's noise).
- **nine_point** (alone): the map a perfect measurement gives at the cell's C_Pos_0 through the
  cell's own lens (the true camera's projection of wall points along T0's axes, distorted by the
  true lens, undistorted by the cell's); against the commissioned set.
- **teaching** (C_Pos_0 and the template as measured by the teaching job): **re-taught** against
  **nine_point** (both carry a perfect map; they differ only in the teaching measurement).
- **g_Pos_0** (alone): the install pose a perfect operator records (the belief that truly seats the
  glass at the nominal car body, as the oracle teaches it); against the commissioned set.
- **all**: the oracle's complete calibration (:func:`cellctl.sim.oracle.oracle_calibration`), against
  the commissioned set: the whole of the calibration's share.

Everything here works on a separate :class:`~cellctl.sim.rig.SimRig` of the cell's seed, never on the
twin the trials run on, so every row's trials draw the same postures and noise streams.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from datetime import datetime
from typing import Any

import numpy as np

from cellctl.cell.cycle_values import CycleCalibration
from cellctl.compensate import TaughtPoses
from cellctl.config import CellConfig
from cellctl.geometry.pose import Pose, apply_pose, invert_pose, mean_pose
from cellctl.vision import Lens, fit_affine_map

REPEATS = 8  # laser alignments and shots averaged in a re-teaching (as the oracle teaches)


@dataclass(frozen=True)
class SwapRow:
    """One row of the budget by part: what is swapped for the truth, and what its effect is read against.

    Attributes:
        key: the row's name (``as-commissioned``, ``g_Pos_0``, ``nine_point``, ``re-taught``, ``camera``, ...).
        part: the part whose effect the row measures (None: a reference row).
        label: how the report names it.
        against: the row whose mean error the effect is taken from (None: a reference row).
        chain: how the part was swapped (alone, or what else went with it).
    """

    key: str
    part: str | None
    label: str
    against: str | None
    chain: str


PART_ROWS: tuple[SwapRow, ...] = (
    SwapRow("as-commissioned", None, "the cell's calibration set, as commissioned", None, ""),
    SwapRow("g_Pos_0", "g_Pos_0", "true g_Pos_0 (teaching's install pose)", "as-commissioned", "alone"),
    SwapRow("nine_point", "nine_point", "true nine-point map", "as-commissioned", "alone (a perfect map for the cell's lens at its C_Pos_0)"),
    SwapRow(
        "re-taught", "teaching", "C_Pos_0 and template re-taught (own parts)", "nine_point",
        "C_Pos_0 and template re-measured (averaged) with the cell's own parts, perfect map; g_Pos_0 and T0 kept",
    ),  # fmt: skip
    SwapRow("camera", "camera", "true camera intrinsics", "re-taught", "with C_Pos_0, template and map re-taught"),
    SwapRow("hand_eye", "hand_eye", "true hand-eye", "re-taught", "with C_Pos_0, template and map re-taught"),
    SwapRow("laser", "laser", "true laser ray r, l", "re-taught", "with C_Pos_0, template and map re-taught"),
    SwapRow("all", None, "all true (oracle calibration)", "as-commissioned", "every part, taught by the oracle"),
)
PARTS: tuple[str, ...] = tuple(r.part for r in PART_ROWS if r.part is not None)
PART_NAMES_FOR_REPORT = {
    "camera": "camera intrinsics",
    "hand_eye": "hand-eye",
    "laser": "laser r/l",
    "nine_point": "nine-point map",
    "teaching": "teaching (C_Pos_0, template)",
    "g_Pos_0": "teaching (g_Pos_0)",
}


@dataclass(frozen=True)
class TrueParts:
    """The twin's true values of the parts (identical in every seed: the mountings are the configuration's)."""

    lens: Lens
    T_H_C: Pose
    laser_r: np.ndarray
    laser_l: np.ndarray


def true_parts(rig: Any, config: CellConfig) -> TrueParts:
    truth = rig.cell.truth()
    return TrueParts(Lens.from_intrinsics(config.sim.camera.intrinsics), truth.T_H_C, truth.laser_r, truth.laser_l)


def _nominal(config: CellConfig) -> Any:
    from cellctl.sim.world import nominal_world

    return nominal_world(config.sim.world)


def perfect_nine_point(rig: Any, config: CellConfig, lens: Lens, C_Pos_0: Pose, T0: Pose) -> Any:
    """The nine-point map a perfect measurement gives at ``C_Pos_0`` for ``lens`` (mm along T0's axes)."""
    from cellctl.sim.oracle import NINE_POINTS_MM

    cell = rig.cell
    world = _nominal(config)
    true_lens = Lens.from_intrinsics(config.sim.camera.intrinsics)
    T_B_C = cell.robot_model.deform(C_Pos_0) @ cell.T_H_C
    wall = apply_pose(world.T_B_T, np.column_stack([NINE_POINTS_MM, np.zeros(len(NINE_POINTS_MM))]))
    labels = ((wall - world.T_B_T[:3, 3]) @ np.asarray(T0)[:3, :3])[:, :2]  # along T0's axes, from the corner
    in_C = apply_pose(invert_pose(T_B_C), wall)
    K = true_lens.camera_matrix
    ideal_true = (in_C[:, :2] / in_C[:, 2:3]) * np.array([K[0, 0], K[1, 1]]) + np.array([K[0, 2], K[1, 2]])
    raw = true_lens.distort(ideal_true)
    return fit_affine_map(lens.undistort(raw), labels)


def reteach(rig: Any, config: CellConfig, cal: CycleCalibration, *, repeats: int = REPEATS) -> CycleCalibration:
    """C_Pos_0, the template and the nine-point map taught again in the twin with ``cal``'s parts.

    As the oracle teaches, with the car body at its nominal placement: ``repeats`` laser alignments
    from the cell's C_Pos_0 (through ``cal``'s laser ray and hand-eye), their mean is C_Pos_0; the
    template is the mean corner of ``repeats`` shots there through ``cal``'s lens; T0 follows from
    them as the commissioning's teaching computes it (the corner's ray on the mean wall plane), so
    the re-taught set is as self-consistent as a taught one; the map is :func:`perfect_nine_point`.
    g_Pos_0 (an absolute pose, taught by hand) stays ``cal``'s.
    """
    from cellctl.calibration.teach import workpiece_frame_from_corner
    from cellctl.sim.oracle import teaching_alignment, template_at

    cell = rig.cell
    current = cell.world()
    world = _nominal(config)
    T0 = cal.taught.T0
    ray = {"laser_r": cal.laser_r, "laser_l": cal.laser_l, "T_H_C": cal.T_H_C, "range_mm": cal.laser_range_mm}
    try:
        cell.place_car_body(world)
        aligned = [teaching_alignment(rig, config, T0, cal.taught.C_Pos_0, **ray) for _ in range(repeats)]
        C_Pos_0 = mean_pose(np.stack([a.T_B_H_aligned for a in aligned]))
        template = template_at(rig, config, C_Pos_0, world, cal.lens, repeats)
    finally:
        cell.place_car_body(current)
    normal = np.mean([a.wall.plane.normal for a in aligned], axis=0)
    normal /= np.linalg.norm(normal)
    offset = float(np.mean([a.wall.plane.offset for a in aligned]))
    T0_taught = workpiece_frame_from_corner(
        C_Pos_0, cal.T_H_C, cal.lens.camera_matrix, [template.u_px, template.v_px], template.theta_rad, normal, offset
    )
    return dataclasses.replace(
        cal,
        taught=TaughtPoses(T0_taught, C_Pos_0, cal.taught.g_Pos_0),
        template=template,
        nine_point=perfect_nine_point(rig, config, cal.lens, C_Pos_0, T0_taught),
    )


def true_g_Pos_0(rig: Any, config: CellConfig) -> Pose:
    """The belief install pose that truly seats the glass with the car body at its nominal placement."""
    cell = rig.cell
    current = cell.world()
    try:
        cell.place_car_body(_nominal(config))
        return cell.install_command()
    finally:
        cell.place_car_body(current)


def swapped_calibrations(
    base: CycleCalibration, config: CellConfig, seed: int, keys: tuple[str, ...] | None = None
) -> dict[str, CycleCalibration]:
    """Each row's calibration (:data:`PART_ROWS`) from the cell's own ``base``, built on a copy of the twin of ``seed``.

    ``keys`` limits the rows (default: all of them).
    """
    from cellctl.sim.oracle import oracle_calibration
    from cellctl.sim.rig import SimRig

    want = [r.key for r in PART_ROWS] if keys is None else list(keys)
    rig = SimRig(config.sim, seed=seed)
    truth = true_parts(rig, config)
    out: dict[str, CycleCalibration] = {"as-commissioned": base}
    retaught: CycleCalibration | None = None

    def own_retaught() -> CycleCalibration:
        nonlocal retaught
        if retaught is None:
            retaught = reteach(rig, config, base)
        return retaught

    for key in want:
        if key == "as-commissioned":
            continue
        if key == "g_Pos_0":
            T = base.taught
            out[key] = dataclasses.replace(base, taught=TaughtPoses(T.T0, T.C_Pos_0, true_g_Pos_0(rig, config)))
        elif key == "nine_point":
            out[key] = dataclasses.replace(base, nine_point=perfect_nine_point(rig, config, base.lens, base.taught.C_Pos_0, base.taught.T0))
        elif key == "re-taught":
            out[key] = own_retaught()
        elif key == "camera":
            out[key] = reteach(rig, config, dataclasses.replace(base, lens=truth.lens))
        elif key == "hand_eye":
            out[key] = reteach(rig, config, dataclasses.replace(base, T_H_C=truth.T_H_C))
        elif key == "laser":
            out[key] = reteach(rig, config, dataclasses.replace(base, laser_r=truth.laser_r, laser_l=truth.laser_l))
        elif key == "all":
            out[key] = oracle_calibration(rig, config)
        else:
            raise ValueError(f"unknown budget row {key!r}; the rows are {', '.join(r.key for r in PART_ROWS)}")
    return out


class FixedCalibrationSource:
    """A CalibrationSource that hands every cycle one fixed calibration (a budget row's)."""

    def __init__(self, cal: CycleCalibration, label: str) -> None:
        self._cal = cal
        self._label = label

    def problems(self, recipe: str | None = None, *, now: datetime | None = None) -> list[str]:
        return []

    def cycle_calibration(self, recipe: str | None = None) -> CycleCalibration:
        return self._cal

    def summary(self, *, now: datetime | None = None) -> dict[str, Any]:
        return {"source": f"bench: {self._label}", "version": 0, "parts": {}}

    def history(self) -> list[dict[str, Any]]:
        return []

    def reference(self, recipe: str | None = None) -> dict[str, Any]:
        return {"source": f"bench: {self._label}", "version": 0}

    def untaught(self, recipe: str) -> str | None:
        return None
