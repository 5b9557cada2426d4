"""Orientation quaternions (w, x, y, z) as both wires carry them: the one convention the driver keeps.

The line protocol (``ORI``, ``GETC``) and EGM (``orient.u0..u3``) carry orientations as
quaternions in ABB's order, and :class:`cellctl.ports.CartesianPose` holds one as it is. What
the ports cannot do for the driver is take a quaternion off the wire: a ``CartesianPose``
refuses a norm more than 1e-6 from 1, and a wire value is not that close (RAPID prints 6
decimals; the controller computes in single precision). So the driver renormalises every
quaternion it puts on or takes off a wire, with w >= 0 (q and -q are the same rotation; the
driver sends and reports the one with w >= 0). The angle between two orientations is the
convergence measure of EGM; the peer's loop computes it on raw wire values 250 times a
second in its own process, where a round trip through the ports' rotation matrices would cost
several times the loop's own work.

Conversions between quaternions and rotation matrices are the ports' (``CartesianPose.to_matrix``
and ``CartesianPose.from_matrix``); they are not repeated here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

Quat = tuple[float, float, float, float]


def unit(w: float, x: float, y: float, z: float) -> Quat | None:
    """The unit quaternion with w >= 0, or None for a zero or non-finite one (the EGM loop's form)."""
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not math.isfinite(n) or n < 1e-12:
        return None
    if w < 0:
        n = -n
    return (w / n, x / n, y / n, z / n)


def normalise(q: Sequence[float]) -> Quat:
    """The unit quaternion with w >= 0; ValueError for anything that is not a usable quaternion."""
    u = unit(*(float(c) for c in q)) if len(q) == 4 else None
    if u is None:
        raise ValueError(f"not a usable quaternion (w, x, y, z): {tuple(q)!r}")
    return u


def angle_between(a: Sequence[float], b: Sequence[float]) -> float:
    """Rotation angle (rad, 0..pi) that takes orientation ``a`` to orientation ``b``."""
    ua, ub = normalise(a), normalise(b)
    d = abs(ua[0] * ub[0] + ua[1] * ub[1] + ua[2] * ub[2] + ua[3] * ub[3])
    return 2.0 * math.acos(min(1.0, d))
