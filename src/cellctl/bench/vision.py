"""Benchmark of the window-corner detector (paper 4.2) against the twin's truth, on one core.

Run ``python -m cellctl.bench.vision``. Prints

- the median time to find the corner in one 2048 x 2048 frame, and its ratio to ``cv2.Canny``
  alone on the same frame (the configured thresholds, full resolution);
- the accuracy over ``--renders`` seeded renders with default noise: corner position error in the
  raw image (median, p99, max, px) and edge-angle error (median, p99, deg), against the limits
  (0.1 px median, 0.3 px p99, 0.02 deg median);
- the same for each surface of a real opening (cellctl.config.surface: a seal band, a flange
  step, a paint edge, marks crossing an edge within 30 mm of the corner, dirt, all of them
  together) over ``--surface-renders`` renders, each car body with its own widths, greys and
  positions drawn in the configured ranges, against those limits and 95 % accepted; and, reported
  beside them, a recipe that teaches the seal's inner edge (a faint edge) against twice the limits;
- the same for each disturbance (a glare spot on an edge, 30 % of one edge covered by a
  wall-coloured or a dark strip, half the contrast, defocus) on the clean opening over
  ``--disturbed-renders`` renders, against twice those limits (as before real openings, so the
  figures compare).

Refusals are counted by reason, and any corner accepted more than 1 px off is reported.

Each render places the car body at a random posture and the camera at a shooting pose after
alignment: square to the wall within 0.3 deg, 400 +- 1 mm away, turned up to 2 deg about its
axis, with the corner up to 20 mm (262 px) from the image centre.
"""

from __future__ import annotations

import argparse
import json
import os
from collections import Counter
from dataclasses import dataclass, field

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from cellctl.bench.timing import median_s  # noqa: E402
from cellctl.bench.vision_args import add_arguments  # noqa: E402
from cellctl.config.render import DisturbanceConfig, GlareConfig, OcclusionConfig, RenderConfig  # noqa: E402
from cellctl.config.sim import SimConfig  # noqa: E402
from cellctl.config.surface import CLEAN_SURFACE, BandConfig, DirtConfig, MarksConfig, SurfaceConfig  # noqa: E402
from cellctl.config.vision import FeatureConfig, VisionConfig  # noqa: E402
from cellctl.geometry.rotation import rot_x, rot_y, rot_z  # noqa: E402
from cellctl.sim.camera import CameraRenderer  # noqa: E402
from cellctl.sim.image_truth import camera_pose_seeing_corner, corner_truth  # noqa: E402
from cellctl.sim.world import World, sample_world  # noqa: E402
from cellctl.vision.corner import detect_corner  # noqa: E402
from cellctl.vision.lens import Lens  # noqa: E402

# Limits of issue 4 (default noise); disturbances are held to twice these.
MEDIAN_LIMIT_PX = 0.1
P99_LIMIT_PX = 0.3
ANGLE_MEDIAN_LIMIT_DEG = 0.02
NEVER_ACCEPT_PX = 1.0

DISTURBANCES: dict[str, DisturbanceConfig] = {
    "glare spot on an edge": DisturbanceConfig(glare=GlareConfig()),
    "30 % of an edge covered (wall-like)": DisturbanceConfig(occlusion=OcclusionConfig(kind="wall_like")),
    "30 % of an edge covered (dark)": DisturbanceConfig(occlusion=OcclusionConfig(kind="dark")),
    "half contrast": DisturbanceConfig(contrast_factor=0.5),
    "defocus (+1.5 px blur)": DisturbanceConfig(defocus_sigma_px=1.5),
}


MIN_ACCEPTED_SHARE = 0.95

_REAL = SurfaceConfig()
SURFACES: dict[str, SurfaceConfig] = {
    "seal band": CLEAN_SURFACE.model_copy(update={"seal": _REAL.seal}),
    "flange step": CLEAN_SURFACE.model_copy(update={"flange": _REAL.flange}),
    "paint edge": CLEAN_SURFACE.model_copy(update={"paint_band": _REAL.paint_band}),
    "marks across an edge within 30 mm of the corner": CLEAN_SURFACE.model_copy(
        update={"marks": MarksConfig(count=(1, 2), within_mm=30.0)}
    ),
    "dirt": CLEAN_SURFACE.model_copy(update={"dirt": DirtConfig()}),
    "the default surface (paint edge, flange, seal)": _REAL,
    "all together (default surface, marks, dirt)": _REAL.model_copy(
        update={"marks": MarksConfig(count=(1, 2), within_mm=30.0), "dirt": DirtConfig()}
    ),
}
SEAL_INNER_EDGE = FeatureConfig(count_from="opening", index=0, min_step_fraction=0.15)
"""A recipe that teaches the seal's inner edge: the first falling step met from the opening."""
SEAL_SURFACE = _REAL.model_copy(
    update={"flange": BandConfig(width_mm=(4.0, 7.0), dn=(70.0, 85.0)), "seal": BandConfig(width_mm=(6.0, 10.0), dn=(50.0, 60.0))}
)
"""A grey seal 30-40 DN above the interior: a quarter of the wall's contrast, so its recipe lowers the
contrast limit, allows more scatter, and is held to twice the limits."""
SEAL_LIMITS = {"min_contrast_dn": 8.0, "max_fit_rms_px": 0.6, "max_corner_sigma_px": 0.25}


def shooting_scene(renderer: CameraRenderer, sim: SimConfig, rng: np.random.Generator) -> tuple[World, NDArray[np.float64]]:
    """A car body at a random posture and the camera at an aligned shooting pose in front of its corner."""
    world = sample_world(sim.world, rng)
    intr = sim.camera.intrinsics
    offset_px = 20.0 * intr.fx / 400.0  # 20 mm at the working distance
    corner = (intr.cx + rng.uniform(-offset_px, offset_px), intr.cy + rng.uniform(-offset_px, offset_px))
    tilt = np.radians(0.3)
    R = rot_x(rng.uniform(-tilt, tilt)) @ rot_y(rng.uniform(-tilt, tilt)) @ rot_z(np.radians(rng.uniform(-2.0, 2.0)))
    pose = camera_pose_seeing_corner(renderer.camera, world, corner, distance_mm=400.0 + rng.uniform(-1.0, 1.0), R_T_C=R)
    return world, pose


@dataclass
class Accuracy:
    """Errors of accepted corners against the truth, and the refusals."""

    renders: int = 0
    corner_err_px: list[float] = field(default_factory=list)
    angle_err_deg: list[float] = field(default_factory=list)
    refusals: Counter[str] = field(default_factory=Counter)

    @property
    def accepted(self) -> int:
        return len(self.corner_err_px)

    def figures(self) -> dict[str, float]:
        c = np.asarray(self.corner_err_px)
        a = np.asarray(self.angle_err_deg)
        if len(c) == 0:
            return {"median": float("nan"), "p99": float("nan"), "max": float("nan"), "angle_median": float("nan"), "angle_p99": float("nan")}
        return {
            "median": float(np.median(c)),
            "p99": float(np.percentile(c, 99)),
            "max": float(np.max(c)),
            "angle_median": float(np.median(a)),
            "angle_p99": float(np.percentile(a, 99)),
        }

    def meets(self, factor: float, min_accepted: float = 0.0) -> bool:
        f = self.figures()
        if self.accepted < min_accepted * self.renders:
            return False
        if self.accepted == 0:
            return True  # everything refused: no wrong corner was returned
        return (
            f["median"] <= factor * MEDIAN_LIMIT_PX
            and f["p99"] <= factor * P99_LIMIT_PX
            and f["angle_median"] <= factor * ANGLE_MEDIAN_LIMIT_DEG
            and f["max"] <= NEVER_ACCEPT_PX
        )


def _inner_seal_inset_mm(frame_surface: object) -> float:
    """How far the innermost step of the drawn surface lies inside the opening's edge (mm)."""
    steps = getattr(frame_surface, "steps", None)
    if not steps:
        return 0.0
    return -float(steps[-1][0])


def measure_accuracy(
    renderer: CameraRenderer,
    sim: SimConfig,
    lens: Lens,
    config: VisionConfig,
    renders: int,
    rng: np.random.Generator,
    *,
    feature_at_seal: bool = False,
) -> Accuracy:
    """Render ``renders`` shooting views, detect the corner and compare with the twin's truth.

    ``feature_at_seal``: the truth is the seal's inner edge (the innermost step drawn), not the wall's.
    """
    acc = Accuracy()
    for _ in range(renders):
        world, pose = shooting_scene(renderer, sim, rng)
        frame = renderer.render(pose, world, rng=rng)
        m = detect_corner(frame.image, lens, config)
        acc.renders += 1
        if not m.ok:
            acc.refusals[m.refusal.value if m.refusal else "?"] += 1
            continue
        inset = _inner_seal_inset_mm(frame.applied.surface) if feature_at_seal else 0.0
        truth = corner_truth(renderer.camera, pose, world, inset_mm=inset)
        assert m.corner_raw_px is not None and m.top is not None and m.right is not None
        acc.corner_err_px.append(float(np.linalg.norm(m.corner_raw_px - truth.corner_px)))
        right_truth = float(np.arctan2(-truth.right_edge_dir_px[0], truth.right_edge_dir_px[1]))
        acc.angle_err_deg.append(abs(float(np.degrees(m.top.angle_rad - truth.edge_angle_rad))))
        acc.angle_err_deg.append(abs(float(np.degrees(m.right.angle_rad - right_truth))))
    return acc


def _report(name: str, acc: Accuracy, factor: float, min_accepted: float = 0.0) -> None:
    f = acc.figures()
    print(f"  {name}: {acc.accepted}/{acc.renders} accepted (refused: {refusal_text(acc.refusals)})")
    print(
        f"    corner error median {f['median']:.4f} px, p99 {f['p99']:.4f} px, max {f['max']:.4f} px; "
        f"edge angle error median {f['angle_median']:.5f} deg, p99 {f['angle_p99']:.5f} deg"
    )
    print(
        f"    limits x{factor:g} (median {factor * MEDIAN_LIMIT_PX:g} px, p99 {factor * P99_LIMIT_PX:g} px, "
        f"angle {factor * ANGLE_MEDIAN_LIMIT_DEG:g} deg, none accepted > {NEVER_ACCEPT_PX:g} px"
        f"{f', at least {min_accepted:.0%} accepted' if min_accepted else ''}): "
        f"{'met' if acc.meets(factor, min_accepted) else 'NOT met'}"
    )


def one_core_camera() -> tuple[SimConfig, Lens, CameraRenderer]:
    """The twin's default settings, its camera's lens and renderer, with OpenCV on one core (the benches' setting)."""
    cv2.setNumThreads(1)
    sim = SimConfig()
    return sim, Lens.from_intrinsics(sim.camera.intrinsics), CameraRenderer(sim.camera.intrinsics, sim.camera.render)


def refusal_text(refusals: Counter[str]) -> str:
    """The refusals counted by reason, as ``reason n, ...`` (``none`` when there are none)."""
    return ", ".join(f"{k} {v}" for k, v in sorted(refusals.items())) or "none"


def _renderer(sim: SimConfig, **update: object) -> CameraRenderer:
    return CameraRenderer(sim.camera.intrinsics, RenderConfig(**{**sim.camera.render.model_dump(), **update}))


def _figures(acc: Accuracy) -> dict[str, object]:
    return {"renders": acc.renders, "accepted": acc.accepted, "refusals": dict(acc.refusals), **acc.figures()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m cellctl.bench.vision", description=__doc__.splitlines()[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))


def run(args: argparse.Namespace) -> int:
    """The benchmark with parsed options (``cellctl bench vision`` calls it too); 0 when every bar is met."""
    if args.runs < 1 or args.renders < 1 or args.disturbed_renders < 0 or args.surface_renders < 0:
        print("bench vision: --runs and --renders must be at least 1, --surface-renders and --disturbed-renders at least 0")
        return 2
    sim, lens, renderer = one_core_camera()
    config = VisionConfig()
    rng = np.random.default_rng(args.seed)
    report: dict[str, object] = {"seed": args.seed}

    times: dict[str, float] = {}
    for label, r in (("default surface", renderer), ("clean opening", _renderer(sim, surface=CLEAN_SURFACE))):
        world, pose = shooting_scene(r, sim, rng)
        image = r.render(pose, world, rng=rng).image
        detect_corner(image, lens, config)  # warm-up
        detect_s = median_s(lambda: detect_corner(image, lens, config), args.runs)
        c = config.coarse
        canny_s = median_s(lambda: cv2.Canny(image, c.canny_low, c.canny_high, L2gradient=c.canny_l2_gradient), args.runs)
        if not times:
            print(f"window-corner detector, {image.shape[1]} x {image.shape[0]} 8-bit, one core, seed {args.seed}")
        print(f"  {label}: median detection {detect_s * 1e3:.1f} ms, cv2.Canny on the same frame {canny_s * 1e3:.1f} ms, "
              f"ratio {detect_s / canny_s:.2f} x (target <= 3 x: {'met' if detect_s <= 3.0 * canny_s else 'NOT met'})")
        times[label] = detect_s / canny_s
    report["detection_over_canny"] = times

    def wanted(name: str) -> bool:
        return args.only.lower() in name.lower()

    print("accuracy against the twin's truth (raw image, corner error = distance to the true corner):")
    all_met = True
    cases: dict[str, object] = {}
    name = f"clean opening, default noise, {args.renders} renders"
    if wanted(name):
        acc = measure_accuracy(_renderer(sim, surface=CLEAN_SURFACE), sim, lens, config, args.renders, rng)
        _report(name, acc, 1.0, 1.0)
        all_met &= acc.meets(1.0, 1.0)
        cases["clean"] = _figures(acc)
    if args.surface_renders:
        print(f"real openings, {args.surface_renders} car bodies each (limits x1, at least {MIN_ACCEPTED_SHARE:.0%} accepted):")
        for name, surface in SURFACES.items():
            if not wanted(name):
                continue
            acc = measure_accuracy(_renderer(sim, surface=surface), sim, lens, config, args.surface_renders, rng)
            _report(name, acc, 1.0, MIN_ACCEPTED_SHARE)
            all_met &= acc.meets(1.0, MIN_ACCEPTED_SHARE)
            cases[name] = _figures(acc)
        name = "the seal's inner edge taught as the feature (a grey seal, 30-40 DN: limits x2)"
        if wanted(name):
            seal_cfg = config.model_copy(
                update={
                    "feature": SEAL_INNER_EDGE,
                    "limits": config.limits.model_copy(update=SEAL_LIMITS),
                    "fit": config.fit.model_copy(update={"level_samples": 4}),
                }
            )
            acc = measure_accuracy(
                _renderer(sim, surface=SEAL_SURFACE), sim, lens, seal_cfg, args.surface_renders, rng, feature_at_seal=True
            )
            _report(name, acc, 2.0, MIN_ACCEPTED_SHARE)
            print("    (reported, not a bar: the sub-pixel estimator's scatter grows as the edge's contrast falls)")
            cases[name] = _figures(acc)
    if args.disturbed_renders:
        print(f"disturbances on the clean opening, {args.disturbed_renders} renders each (limits x2):")
        for name, dist in DISTURBANCES.items():
            if not wanted(name):
                continue
            d_acc = measure_accuracy(
                _renderer(sim, disturbances=dist, surface=CLEAN_SURFACE), sim, lens, config, args.disturbed_renders, rng
            )
            _report(name, d_acc, 2.0)
            all_met &= d_acc.meets(2.0)
            cases[name] = _figures(d_acc)
    report["cases"] = cases
    report["all_met"] = bool(all_met)
    print(f"all accuracy limits: {'met' if all_met else 'NOT met'}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(report, fh, indent=2)
    return 0 if all_met else 1


if __name__ == "__main__":
    raise SystemExit(main())
