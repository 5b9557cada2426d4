"""``robot_clear`` (``cycle_flags`` bit 9): the robot's flange stands far enough in front of the car body's wall.

Pure: the service's PLC link reads the robot's pose and the last cycle's wall plane and feeds them in
(:class:`ClearanceWatch`); nothing here does I/O.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class FittedWall:
    """A cycle's fitted wall plane in the robot's base frame B: points p on it satisfy ``normal . p = offset_mm``;
    ``normal`` is a unit vector pointing into the wall (the alignment's convention, eq. 2)."""

    normal: tuple[float, float, float]
    offset_mm: float

    def __post_init__(self) -> None:
        n = tuple(float(v) for v in self.normal)
        if len(n) != 3 or not all(math.isfinite(v) for v in n) or abs(math.hypot(*n) - 1.0) > 1e-6:
            raise ValueError(f"wall normal must be a finite unit 3-vector, got {self.normal!r}")
        if not math.isfinite(self.offset_mm):
            raise ValueError(f"wall offset_mm must be finite, got {self.offset_mm!r}")
        object.__setattr__(self, "normal", n)

    @classmethod
    def from_record(cls, fields: Mapping[str, Any] | None) -> FittedWall | None:
        """The plane a done cycle's record keeps under ``result["wall_plane_B"]``; None when absent or malformed."""
        if not isinstance(fields, Mapping):
            return None
        try:
            return cls(tuple(fields["normal"]), float(fields["offset_mm"]))  # type: ignore[arg-type]
        except (KeyError, TypeError, ValueError):
            return None


def flange_to_wall_mm(flange_position_mm: Sequence[float], wall: FittedWall) -> float:
    """Signed distance (mm) of the flange origin from the wall along its normal: + in front of it (the robot's side)."""
    p = [float(v) for v in flange_position_mm]
    return wall.offset_mm - sum(n * x for n, x in zip(wall.normal, p, strict=True))


@dataclass(frozen=True)
class _Reading:
    at_s: float
    clear: bool


class ClearanceWatch:
    """The latest verdict of the poller, valid only if no cycle ran since its reading began and only for ``max_age_s``.

    The poller calls :meth:`begin` before it reads the pose and :meth:`settle` after; the scan calls
    :meth:`cycle_running` whenever a cycle runs (or the robot moves), which voids readings begun before it.
    """

    def __init__(self, clear_distance_mm: float, max_age_s: float) -> None:
        if not (clear_distance_mm > 0 and math.isfinite(clear_distance_mm)):
            raise ValueError(f"plc.clear_distance_mm must be a positive number of mm, got {clear_distance_mm!r}")
        self.clear_distance_mm = float(clear_distance_mm)
        self.max_age_s = float(max_age_s)
        self._generation = 0
        self._reading: _Reading | None = None

    def cycle_running(self) -> None:
        """A cycle runs (or the robot moves): not clear, and readings begun before now do not count."""
        self._generation += 1
        self._reading = None

    def begin(self) -> int:
        """A token for a reading that starts now."""
        return self._generation

    def settle(self, token: int, at_s: float, distance_mm: float | None) -> None:
        """The reading begun with ``token``: the flange's distance in front of the wall (None: unknown)."""
        if token != self._generation:
            return  # a cycle ran meanwhile: the pose may be another's
        self._reading = _Reading(at_s, distance_mm is not None and distance_mm >= self.clear_distance_mm)

    def clear(self, now_s: float) -> bool:
        """``robot_clear`` now: a fresh reading said clear."""
        r = self._reading
        return r is not None and r.clear and 0.0 <= now_s - r.at_s <= self.max_age_s
