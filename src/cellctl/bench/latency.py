"""Benchmark of the on-the-fly laser latency (issue 19): how well it is estimated, and what it buys.

(a) A calibration move against a flat wall (60 mm toward the wall along the beam while 60 mm
sideways, then 60 mm away while 60 mm in the other sideways direction, 250 mm/s) with a latency
drawn in 5..15 ms, the feedback's time stamps jittered by +-0.2 ms and sensor noise of 0.005 mm:
the estimation error. (b) An L-shaped sweep (2000 mm along x, then 1500 mm along y) 350 mm past a
wall tilted up to +-2 deg, at 500 and 1000 mm/s, true latency 10 ms: the wall plane's error when the
readings are paired with the latency estimated by (a)'s move, with none (0 ms), with the true one,
and with one estimated from the sweep itself.

Run: ``python -m cellctl.bench.latency --seeds 20``. The trajectory is the twin's own: trapezoidal
legs (:class:`cellctl.geometry.motion.TrapezoidProfile`), the flange turning at a constant rate.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.align.onthefly import (
    estimate_latency,
    pair_stored_readings,
    pose_samples_arrays,
    stored_instants,
)
from cellctl.geometry.motion import TrapezoidProfile
from cellctl.geometry.plane import fit_plane
from cellctl.geometry.rotation import axis_angle_to_matrix, rot_x, rot_y
from cellctl.ports import CartesianPose, PoseSample, StoredReadings

F64 = NDArray[np.float64]

FEEDBACK_S = 0.004
JITTER_S = 0.0002
CYCLE_S = 0.001
NOISE_MM = 0.005
STANDOFF_MM = 350.0
R_LASER = np.array([30.0, -15.0, 95.0])
L_LASER = np.array([0.02, 0.01, 1.0]) / np.linalg.norm([0.02, 0.01, 1.0])
R_DOWN = rot_x(np.pi)  # tool z, and the beam, point down at the wall
SWEEP_DELTA_S = 0.010
SPEEDS_MM_S = (500.0, 1000.0)
CALIBRATION_LEGS = ((60.0, 0.0, -60.0), (0.0, 60.0, 60.0))
SWEEP_LEGS = ((2000.0, 0.0, 0.0), (0.0, 1500.0, 0.0))


@dataclass(frozen=True)
class Move:
    """Straight rest-to-rest legs from ``start`` (mm), the flange turning by ``turn_rotvec`` (rad) over the move."""

    start: F64
    legs: tuple[tuple[float, float, float], ...]
    speed_mm_s: float
    acceleration_mm_s2: float
    turn_rotvec: F64

    def profiles(self) -> list[TrapezoidProfile]:
        """The legs' speed profiles (mm, mm/s, mm/s^2)."""
        return [TrapezoidProfile(float(np.linalg.norm(g)), self.speed_mm_s, self.acceleration_mm_s2) for g in self.legs]

    @property
    def duration_s(self) -> float:
        """Time from rest to rest over all legs (s)."""
        return sum(p.duration for p in self.profiles())

    def poses(self, t: F64) -> F64:
        """(M, 4, 4) true flange poses T_B_H at the instants ``t`` (s from the move's start)."""
        out = np.zeros((t.size, 4, 4))
        out[:, 3, 3] = 1.0
        p = np.tile(self.start, (t.size, 1))
        begin = 0.0
        for g, prof in zip(self.legs, self.profiles()):
            s = np.array([prof.travelled(x - begin) for x in t])
            p += s[:, None] * (np.asarray(g) / prof.distance)
            begin += prof.duration
        frac = np.clip(t / begin, 0.0, 1.0)
        out[:, :3, 3] = p
        out[:, :3, :3] = [axis_angle_to_matrix(f * self.turn_rotvec) @ R_DOWN for f in frac]
        return out


@dataclass(frozen=True)
class Wall:
    """A flat wall ``normal . p = offset`` (mm), the normal pointing away from the sensor."""

    normal: F64
    offset: float

    def distances(self, T: F64) -> F64:
        """Where the beam r + d l of each flange pose meets the wall (d in mm)."""
        o = np.einsum("nij,j->ni", T[:, :3, :3], R_LASER) + T[:, :3, 3]
        u = np.einsum("nij,j->ni", T[:, :3, :3], L_LASER)
        return (self.offset - o @ self.normal) / (u @ self.normal)


def tilted_wall(rng: np.random.Generator, max_deg: float) -> Wall:
    """A wall at z = 0 tilted about x and y by up to ``max_deg`` each (a car body out of its posture)."""
    ax, ay = np.radians(rng.uniform(-max_deg, max_deg, 2))
    return Wall(rot_y(ay) @ rot_x(ax) @ np.array([0.0, 0.0, -1.0]), 0.0)


def record(move: Move, wall: Wall, delta_s: float, rng: np.random.Generator) -> tuple[StoredReadings, tuple[PoseSample, ...]]:
    """What the cell gets: feedback every 4 ms (stamps jittered) and readings every 1 ms, true at t - delta."""
    end = move.duration_s + 0.15
    true_t = np.arange(-0.15, end, FEEDBACK_S)
    stamps = true_t + rng.uniform(-JITTER_S, JITTER_S, true_t.size)
    samples = tuple(PoseSample(float(s), CartesianPose.from_matrix(T)) for s, T in zip(stamps, move.poses(true_t)))
    started = float(rng.uniform(-0.1, -0.05))
    instants = started + CYCLE_S * np.arange(int((end - 0.1 - started) / CYCLE_S))
    d = wall.distances(move.poses(instants - delta_s)) + rng.normal(0.0, NOISE_MM, instants.size)
    return StoredReadings(started, CYCLE_S, tuple(float(x) for x in d)), samples


def estimate(stored: StoredReadings, samples: tuple[PoseSample, ...]) -> float:
    """The latency (s) estimated from a recorded move."""
    instants, d = stored_instants(stored)
    t, T = pose_samples_arrays(samples)
    return estimate_latency(instants, d, t, T, R_LASER, L_LASER).latency_s


def calibration_move(rng: np.random.Generator) -> Move:
    """The calibration move of part (a), starting near 350 mm from the wall, turning by about 0.6 deg."""
    start = np.array([0.0, 0.0, STANDOFF_MM + 95.0]) + rng.uniform(-20.0, 20.0, 3)
    return Move(start, CALIBRATION_LEGS, 250.0, 2500.0, np.radians([0.3, -0.2, 0.5]))


def plane_error(points: F64, wall: Wall, corner: F64) -> tuple[float, float]:
    """(normal angle in deg, offset along the normal at ``corner`` in mm) of the plane fitted to ``points``."""
    fit = fit_plane(points)
    cos = abs(float(fit.normal @ wall.normal))
    return float(np.degrees(np.arccos(min(cos, 1.0)))), abs(float(fit.normal @ corner - fit.offset))


def run_latency_bench(seeds: int, seed: int) -> dict[str, Any]:
    """Both parts over ``seeds`` random cells from ``seed``; medians, p95 and maxima of the errors."""
    rng = np.random.default_rng(seed)
    cal_err_ms = []
    sweep: dict[float, dict[str, list[tuple[float, float]]]] = {
        v: {"estimated": [], "uncompensated": [], "true": [], "self": []} for v in SPEEDS_MM_S
    }
    refused: dict[float, int] = {v: 0 for v in SPEEDS_MM_S}
    for _ in range(seeds):
        delta = float(rng.uniform(0.005, 0.015))
        flat = tilted_wall(rng, 2.0)
        cal_err_ms.append((estimate(*record(calibration_move(rng), flat, delta, rng)) - delta) * 1e3)
        wall = tilted_wall(rng, 2.0)
        est = estimate(*record(calibration_move(rng), wall, SWEEP_DELTA_S, rng))
        for v in SPEEDS_MM_S:
            move = Move(np.array([0.0, 0.0, STANDOFF_MM + 95.0]), SWEEP_LEGS, v, 4000.0, np.radians([0.0, 0.0, 1.0]))
            stored, samples = record(move, wall, SWEEP_DELTA_S, rng)
            T_corner = move.poses(np.array([move.profiles()[0].duration]))
            corner = (T_corner[0, :3, :3] @ (R_LASER + wall.distances(T_corner)[0] * L_LASER)) + T_corner[0, :3, 3]
            try:
                own = estimate(stored, samples)
            except ValueError:
                refused[v] += 1
                own = None
            for name, latency in (("estimated", est), ("uncompensated", 0.0), ("true", SWEEP_DELTA_S), ("self", own)):
                if latency is not None:
                    paired = pair_stored_readings(stored, samples, latency)
                    sweep[v][name].append(plane_error(paired.points(R_LASER, L_LASER), wall, corner))
    err = np.abs(np.array(cal_err_ms))
    figures: dict[str, Any] = {
        "seeds": seeds,
        "seed": seed,
        "calibration_error_ms": {
            "median": float(np.median(err)),
            "p95": float(np.percentile(err, 95)),
            "max": float(np.max(err)),
            "mean_signed": float(np.mean(cal_err_ms)),
        },
        "sweep": {},
    }
    for v in SPEEDS_MM_S:
        row: dict[str, Any] = {"self_refused": refused[v]}
        for name, values in sweep[v].items():
            a = np.array(values).reshape(-1, 2)
            row[name] = {
                "angle_deg_median": float(np.median(a[:, 0])) if a.size else float("nan"),
                "offset_mm_median": float(np.median(a[:, 1])) if a.size else float("nan"),
                "angle_deg_max": float(np.max(a[:, 0])) if a.size else float("nan"),
                "offset_mm_max": float(np.max(a[:, 1])) if a.size else float("nan"),
            }
        for key in ("angle_deg_median", "offset_mm_median"):
            row[f"ratio_{key}"] = row["uncompensated"][key] / row["estimated"][key]
        figures["sweep"][f"{v:g}"] = row
    return figures


def format_latency(figures: dict[str, Any]) -> str:
    """The bench's figures as a few lines of text."""
    c = figures["calibration_error_ms"]
    lines = [
        f"latency bench: {figures['seeds']} seeds from {figures['seed']}",
        (
            f"(a) calibration move, latency 5..15 ms, jitter +-{JITTER_S * 1e3:g} ms, noise {NOISE_MM} mm: "
            f"|error| median {c['median'] * 1e3:.2f} us, p95 {c['p95'] * 1e3:.2f} us, max {c['max'] * 1e3:.2f} us "
            f"(mean signed {c['mean_signed'] * 1e3:+.2f} us)"
        ),
        (
            f"(b) L sweep 2000 x 1500 mm, wall tilted +-2 deg at {STANDOFF_MM:g} mm, true latency "
            f"{SWEEP_DELTA_S * 1e3:g} ms: plane error medians (normal deg / offset at the corner mm)"
        ),
    ]
    for v, row in figures["sweep"].items():
        parts = [
            f"{name} {row[name]['angle_deg_median']:.5f} deg / {row[name]['offset_mm_median']:.4f} mm"
            for name in ("estimated", "uncompensated", "true", "self")
        ]
        lines.append(f"  {v} mm/s: " + "; ".join(parts))
        lines.append(
            f"  {v} mm/s: uncompensated / estimated = {row['ratio_angle_deg_median']:.0f}x (angle), "
            f"{row['ratio_offset_mm_median']:.0f}x (offset); self-estimate refused {row['self_refused']} times"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    figures = run_latency_bench(args.seeds, args.seed)
    print(format_latency(figures))
    print(f"wall time {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
