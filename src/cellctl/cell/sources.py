"""What the orchestrator reads besides its devices: the calibration source, and in simulation the twin's truth."""

from __future__ import annotations

from datetime import datetime
from typing import Any, Protocol, runtime_checkable

from cellctl.cell.cycle_values import CycleCalibration
from cellctl.domain import InstallDeviation


class CalibrationSource(Protocol):
    """Where the cycle's calibration comes from (the versioned calibration set)."""

    def problems(self, recipe: str | None = None, *, now: datetime | None = None) -> list[str]:
        """What keeps ``recipe`` (None: the first) from production (missing, failed, out of date) at ``now`` (None: the
        clock's; a document of several verdicts gives them one); empty when ready."""
        ...

    def cycle_calibration(self, recipe: str | None = None) -> CycleCalibration:
        """The parts a cycle of ``recipe`` needs (the cell's, and the recipe's teaching); only when :meth:`problems` is empty."""
        ...

    def summary(self, *, now: datetime | None = None) -> dict[str, Any]:
        """Versions, dates and quality figures for the records and the dashboard; each recipe's verdict at ``now``."""
        ...

    def history(self) -> list[dict[str, Any]]:
        """Every version of the set, oldest first: number, time, note, each part's status."""
        ...

    def reference(self, recipe: str | None = None) -> dict[str, Any]:
        """Which calibration a cycle of ``recipe`` uses, in a few fields: the set's version and each part's id."""
        ...

    def untaught(self, recipe: str) -> str | None:
        """Why ``recipe`` is not taught in a calibrated cell (its teaching missing or failed), with the fix; else None."""
        ...


@runtime_checkable
class RecipePartsCheck(Protocol):
    """A calibration source that keeps each recipe's own parts (the calibration set; the oracle is always ready)."""

    def recipe_problems(self, recipe: str) -> list[str]:
        """What keeps ``recipe``'s own parts (teaching, nine-point map) from production, one line each naming the fix;
        [] when they are ready, or when there is no usable set (the cycle then fails with the set's own problem)."""
        ...


class SimTruth(Protocol):
    """The twin's knowledge, for simulated cycles only."""

    def new_car_body(self, recipe: str | None = None) -> None:
        """The next car body arrives (a new random posture), built for ``recipe``."""
        ...

    def install_error(self) -> InstallDeviation:
        """The true install error of the glass where it stands now (the paper's six figures)."""
        ...
