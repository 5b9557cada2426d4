"""Benchmark of the post-install inspection image (issue 16) against the twin's truth, on one core.

Run ``python -m cellctl.bench.inspection_vision [--renders 200] [--seed 1]``. Each render places a
car body at a random posture (``[sim.world]``, the default surface of ``[sim.camera.render]``)
with a glass installed at a random deviation from the opening (dX, dY, dZ uniform within
+-``--offset-mm``, dRx, dRy, dRz within +-``--angle-deg``), and the camera at the inspection's
shooting pose: square to the wall as the alignment leaves it (within 0.03 deg), 400 +- 0.2 mm
away, turned up to 0.05 deg about its axis, the corner within 0.3 mm of the taught template (the
principal point). The nine-point map is the taught pose's, exact; the parallax correction gets
the glass's true depth at its corner (the laser's flush, without its noise).

:func:`cellctl.vision.gap.measure_gaps` and :func:`cellctl.vision.gap.in_plane_from_gaps` give
the in-plane figures; against the truth (cellctl.sim.image_truth.glass_truth) it prints the
median and p99 of the errors of dX, dY, their vector, dRz, and the two gaps, the refusals, and
the median measurement time, against the bars 0.02 mm and 0.01 deg.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections import Counter
from dataclasses import dataclass, field

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from cellctl.bench.vision import one_core_camera, refusal_text  # noqa: E402
from cellctl.config.sim import SimConfig  # noqa: E402
from cellctl.config.vision import GapVisionConfig  # noqa: E402
from cellctl.geometry.pose import Pose, apply_pose, invert_pose, make_pose  # noqa: E402
from cellctl.geometry.rotation import rot_x, rot_y, rot_z, xyz_fixed_to_matrix  # noqa: E402
from cellctl.sim.camera import CameraRenderer  # noqa: E402
from cellctl.sim.glass import InstalledGlass, glass_scene  # noqa: E402
from cellctl.sim.image_truth import camera_pose_seeing_corner, glass_truth  # noqa: E402
from cellctl.sim.world import World, sample_world  # noqa: E402
from cellctl.vision.corner import CornerFeatures  # noqa: E402
from cellctl.vision.gap import in_plane_from_gaps, measure_gaps  # noqa: E402
from cellctl.vision.lens import Lens  # noqa: E402
from cellctl.vision.ninepoint import AffineMap, fit_affine_map  # noqa: E402

POSITION_BAR_MM = 0.02
ANGLE_BAR_DEG = 0.01
WORKING_DISTANCE_MM = 400.0
FIGURES = ("dx_mm", "dy_mm", "position_mm", "drz_deg", "top_gap_mm", "right_gap_mm")


@dataclass(frozen=True)
class InspectionScene:
    """One rendered situation: the car body, its glass, the camera, the taught template and map."""

    world: World
    glass: InstalledGlass
    T_B_C: Pose
    template: CornerFeatures
    nine_point: AffineMap


def taught_view(renderer: CameraRenderer, world: World, corner_px: tuple[float, float], distance_mm: float) -> tuple[CornerFeatures, AffineMap]:
    """The template and the exact nine-point map of a camera square onto ``world``'s corner at ``corner_px``."""
    lens = renderer.camera
    pose = camera_pose_seeing_corner(lens, world, corner_px, distance_mm=distance_mm)
    grid = np.array([(x, y) for y in (-20.0, 0.0, 20.0) for x in (-20.0, 0.0, 20.0)])
    P_C = apply_pose(invert_pose(pose) @ world.T_B_T, np.column_stack([grid, np.zeros(len(grid))]))
    ideal = np.column_stack([lens.fx * P_C[:, 0] / P_C[:, 2] + lens.cx, lens.fy * P_C[:, 1] / P_C[:, 2] + lens.cy])
    return CornerFeatures(float(ideal[4, 0]), float(ideal[4, 1]), 0.0, 0.0, 0.0), fit_affine_map(ideal, grid)


def glass_at(sim: SimConfig, world: World, deviation: NDArray[np.float64]) -> InstalledGlass:
    """The glass installed at (dX, dY, dZ mm, dRx, dRy, dRz rad) from the opening (E = inv(T) @ G)."""
    dx, dy, dz, rx, ry, rz = (float(v) for v in deviation)
    E = make_pose(xyz_fixed_to_matrix(rz, ry, rx), [dx, dy, dz])
    return glass_scene(sim.glass, world, world.T_B_T @ E)


def inspection_scene(
    renderer: CameraRenderer, sim: SimConfig, rng: np.random.Generator, *, offset_mm: float = 0.5, angle_deg: float = 0.2
) -> InspectionScene:
    """A car body at a random posture, a glass at a random deviation, the camera at the shooting pose."""
    world = sample_world(sim.world, rng)
    dev = np.concatenate([rng.uniform(-offset_mm, offset_mm, 3), np.radians(rng.uniform(-angle_deg, angle_deg, 3))])
    glass = glass_at(sim, world, dev)
    corner_px = (renderer.camera.cx, renderer.camera.cy)
    template, nine_point = taught_view(renderer, world, corner_px, WORKING_DISTANCE_MM)
    shift_px = 0.3 * renderer.camera.fx / WORKING_DISTANCE_MM
    here = (corner_px[0] + rng.uniform(-shift_px, shift_px), corner_px[1] + rng.uniform(-shift_px, shift_px))
    tilt = np.radians(0.03)
    R = rot_x(rng.uniform(-tilt, tilt)) @ rot_y(rng.uniform(-tilt, tilt)) @ rot_z(np.radians(rng.uniform(-0.05, 0.05)))
    pose = camera_pose_seeing_corner(
        renderer.camera, world, here, distance_mm=WORKING_DISTANCE_MM + rng.uniform(-0.2, 0.2), R_T_C=R
    )
    return InspectionScene(world, glass, pose, template, nine_point)


@dataclass
class InspectionAccuracy:
    """Errors of the accepted measurements against the truth, the refusals and the times."""

    renders: int = 0
    errors: dict[str, list[float]] = field(default_factory=lambda: {k: [] for k in FIGURES})
    refusals: Counter[str] = field(default_factory=Counter)
    times_s: list[float] = field(default_factory=list)

    @property
    def accepted(self) -> int:
        return len(self.errors["dx_mm"])

    def figures(self) -> dict[str, dict[str, float]]:
        """Median, p99 and max of each |error|."""
        out = {}
        for k, v in self.errors.items():
            a = np.abs(np.asarray(v, dtype=float))
            nan = float("nan")
            out[k] = {
                "median": float(np.median(a)) if len(a) else nan,
                "p99": float(np.percentile(a, 99)) if len(a) else nan,
                "max": float(np.max(a)) if len(a) else nan,
            }
        return out

    def meets(self) -> bool:
        """p99 within the bars (0.02 mm per position figure, 0.01 deg), everything accepted."""
        f = self.figures()
        return (
            self.accepted == self.renders
            and all(f[k]["p99"] <= POSITION_BAR_MM for k in ("dx_mm", "dy_mm", "top_gap_mm", "right_gap_mm"))
            and f["drz_deg"]["p99"] <= ANGLE_BAR_DEG
        )


def measure_inspection(
    renderer: CameraRenderer, sim: SimConfig, lens: Lens, config: GapVisionConfig, renders: int, rng: np.random.Generator,
    **scene_ranges: float,
) -> InspectionAccuracy:
    """Render ``renders`` inspection views, measure the gaps and compare with the twin's truth."""
    acc = InspectionAccuracy()
    gap = sim.glass.edge_gap_mm
    for _ in range(renders):
        scene = inspection_scene(renderer, sim, rng, **scene_ranges)
        image = renderer.render(scene.T_B_C, scene.world, rng=rng, glass=scene.glass).image
        acc.renders += 1
        t0 = time.perf_counter()
        m = measure_gaps(image, lens, scene.template, config, gap_px_expected=gap / scene.nine_point.mm_per_px)
        acc.times_s.append(time.perf_counter() - t0)
        if not m.ok:
            acc.refusals[m.refusal.value if m.refusal else "?"] += 1
            continue
        dz = float((invert_pose(scene.world.T_B_T) @ scene.glass.T_B_G)[2, 3])  # the laser's flush at the corner
        fig = in_plane_from_gaps(
            m, scene.nine_point, nominal_gap_mm=gap, dz_mm=dz, working_distance_mm=WORKING_DISTANCE_MM,
            principal_point_px=(lens.cx, lens.cy),
        )
        truth = glass_truth(renderer.camera, scene.T_B_C, scene.world, scene.glass, reference_along_mm=fig.reference_along_mm)
        e = acc.errors
        e["dx_mm"].append(fig.dx_mm - truth.dx_mm)
        e["dy_mm"].append(fig.dy_mm - truth.dy_mm)
        e["position_mm"].append(float(np.hypot(fig.dx_mm - truth.dx_mm, fig.dy_mm - truth.dy_mm)))
        e["drz_deg"].append(float(np.degrees(fig.drz_rad - truth.drz_rad)))
        e["top_gap_mm"].append(fig.top_gap_mm - truth.top_gap_mm)
        e["right_gap_mm"].append(fig.right_gap_mm - truth.right_gap_mm)
    return acc


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m cellctl.bench.inspection_vision", description=__doc__.splitlines()[0])
    parser.add_argument("--renders", type=int, default=200, help="seeded renders (default 200)")
    parser.add_argument("--seed", type=int, default=1, help="the renders' random stream (default 1)")
    parser.add_argument("--offset-mm", type=float, default=0.5, help="glass deviation range, +- mm per axis (default 0.5)")
    parser.add_argument("--angle-deg", type=float, default=0.2, help="glass deviation range, +- deg per axis (default 0.2)")
    parser.add_argument("--json", default=None, help="write the figures to this file")
    args = parser.parse_args(argv)
    if args.renders < 1:
        print("bench inspection_vision: --renders must be at least 1")
        return 2
    sim, lens, renderer = one_core_camera()
    acc = measure_inspection(
        renderer, sim, lens, GapVisionConfig(), args.renders, np.random.default_rng(args.seed),
        offset_mm=args.offset_mm, angle_deg=args.angle_deg,
    )
    refused = refusal_text(acc.refusals)
    print(
        f"inspection image (gaps and in-plane offset), {acc.renders} renders, seed {args.seed}, glass within "
        f"+-{args.offset_mm:g} mm and +-{args.angle_deg:g} deg, default surface: {acc.accepted}/{acc.renders} accepted "
        f"(refused: {refused}); median measurement {1e3 * float(np.median(acc.times_s)):.1f} ms"
    )
    f = acc.figures()
    for k in FIGURES:
        unit = "deg" if k.endswith("deg") else "mm"
        print(f"  |{k[:-3] if unit == 'mm' else k[:-4]} error|: median {f[k]['median']:.4f} {unit}, p99 {f[k]['p99']:.4f} {unit}, max {f[k]['max']:.4f} {unit}")
    met = acc.meets()
    print(f"bars: p99 <= {POSITION_BAR_MM:g} mm (dX, dY, gaps), <= {ANGLE_BAR_DEG:g} deg (dRz), all accepted: {'met' if met else 'NOT met'}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump({"renders": acc.renders, "accepted": acc.accepted, "refusals": dict(acc.refusals), "figures": f}, fh, indent=1)
    return 0 if met else 1


if __name__ == "__main__":
    raise SystemExit(main())
