"""Independent random streams, one per error source of the twin.

Every source (car-body posture, robot accuracy and repeatability, laser linearity and noise,
camera noise...) draws from its own generator, seeded by the cell's seed and the source's name.
Switching one source off, or drawing more from it, leaves the draws of every other source
unchanged, so experiments that vary one error source compare like with like.
"""

from __future__ import annotations

import zlib

import numpy as np

# Names of the streams the twin uses. A new source adds a name; existing streams never change.
WORLD_POSTURE = "world.posture"
ROBOT_ACCURACY = "robot.accuracy"
ROBOT_REPEATABILITY = "robot.repeatability"
LASER_LINEARITY = "laser.linearity"
LASER_NOISE = "laser.noise"
LASER_GLASS = "laser.glass"  # noise and dropout of readings on an installed glass


def rng_stream(seed: int, source: str) -> np.random.Generator:
    """The generator of ``source`` for ``seed``: the same pair always gives the same draws.

    The stream is keyed by the seed and a CRC-32 of the name, so streams of different sources are
    statistically independent (numpy's SeedSequence mixes both words).
    """
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if not source:
        raise ValueError("source must name the error source, e.g. 'laser.noise'")
    return np.random.default_rng(np.random.SeedSequence([int(seed), zlib.crc32(source.encode("utf-8"))]))
