"""The simulated controller's data storage (``AQ``, ``AS``, ``AP``, ``AN``, ``AO``; keyence_lkg.storage).

``AS`` starts storing the OUTs the setup names (LK-G5001 ``SW,OK``, LK-G3001 ``SW,CI``) every
storage cycle (sampling cycle ``CA`` times the setup's multiplier), up to the setup's count; the
fake's serving thread takes each reading for its instant: from a source that can say what it read
then (keyence_lkg.fake_commands.TimedSource, as the twin can), exactly as the controller's clock
would; from any other source when the thread gets there (on a busy host, late: how often is
:attr:`StorageState.late`); ``AP`` stops, ``AN`` tells whether it still
stores and how many it holds, ``AO,<OUT>`` sends them in one line (refused while storing).
A wrong argument count is refused with 21 / 61, a bad or unstored OUT with 22 / 62 (keyence_lkg.md A6).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

from keyence_lkg.errors import PARAMETER_COUNT_ERROR, PARAMETER_ERROR, STATUS_ERROR, Dialect
from keyence_lkg.storage import SAMPLING_CYCLE_US, STORAGE_MULTIPLIERS
from keyence_lkg.units import NO_VALUE


class Refuse(Exception):
    """The controller answers ``ER,<main>,<code>`` (raised by every command handler, keyence_lkg.fake_commands too)."""

    def __init__(self, code: str) -> None:
        self.code = code


@dataclass
class StorageState:
    """What the storage holds and how far it got."""

    storing: bool = False
    outs: tuple[int, ...] = ()
    cycle_s: float = 0.0
    count: int = 0
    started_at: float = 0.0  # time.monotonic() of the first reading
    values: dict[int, list[str]] = field(default_factory=dict)
    late: int = 0  # readings taken more than one cycle after their instant
    worst_late_s: float = 0.0

    @property
    def taken(self) -> int:
        return len(self.values[self.outs[0]]) if self.outs else 0

    def next_due_s(self, now: float) -> float | None:
        """Seconds until the next reading is due (0: overdue), or None when not storing."""
        if not self.storing:
            return None
        return max(0.0, self.started_at + self.taken * self.cycle_s - now)


class StorageCommands:
    """The storage commands of the fake controller (mixed into keyence_lkg.fake_commands.LkgCommandSet)."""

    # provided by LkgCommandSet: the controller's model, a setting's value (written or default), an OUT's token
    dialect: Dialect
    storage: StorageState
    _setting_of: Callable[[str, tuple[str, ...]], tuple[str, ...]]
    _display: Callable[[int, float | None], tuple[str, float | None]]

    def _storage_setup(self) -> tuple[tuple[int, ...], float, int]:
        """The OUTs to store, the storage cycle (s) and the count, from the settings the PC wrote."""
        sampling_s = SAMPLING_CYCLE_US[self.dialect][int(self._setting_of("CA", ())[0])] * 1e-6
        if self.dialect == "LK-G3001":
            out, count, code = self._setting_of("CI", ())
            return (int(out),), sampling_s * STORAGE_MULTIPLIERS[int(code)], int(count)
        count, code = self._setting_of("CF", ())
        outs = tuple(o for o in range(1, 13) if self._setting_of("OK", (f"{o:02d}",))[0] == "1")
        return outs, sampling_s * STORAGE_MULTIPLIERS[int(code)], int(count)

    def _aq(self, main: str, params: list[str]) -> tuple[str, tuple[float | None, ...]]:
        if params:
            raise Refuse(PARAMETER_COUNT_ERROR[self.dialect])
        if self.storage.storing:
            raise Refuse(STATUS_ERROR[self.dialect])
        self.storage = StorageState()
        return "AQ", ()

    def _as(self, main: str, params: list[str]) -> tuple[str, tuple[float | None, ...]]:
        if params:
            raise Refuse(PARAMETER_COUNT_ERROR[self.dialect])
        outs, cycle_s, count = self._storage_setup()
        if not outs or count < 1:
            raise Refuse(STATUS_ERROR[self.dialect])  # no OUT to store
        self.storage = StorageState(True, outs, cycle_s, count, time.monotonic(), {o: [] for o in outs})
        self.sample_storage(self.storage.started_at)
        return "AS", ()

    def _ap(self, main: str, params: list[str]) -> tuple[str, tuple[float | None, ...]]:
        if params:
            raise Refuse(PARAMETER_COUNT_ERROR[self.dialect])
        self.storage.storing = False
        return "AP", ()

    def _an(self, main: str, params: list[str]) -> tuple[str, tuple[float | None, ...]]:
        if params:
            raise Refuse(PARAMETER_COUNT_ERROR[self.dialect])
        return f"AN,{int(self.storage.storing)},{self.storage.taken}", ()

    def _ao(self, main: str, params: list[str]) -> tuple[str, tuple[float | None, ...]]:
        if len(params) != 1:
            raise Refuse(PARAMETER_COUNT_ERROR[self.dialect])  # wrong argument count: 21 / 61
        if not params[0].isdigit():
            raise Refuse(PARAMETER_ERROR[self.dialect])  # bad value: 22 / 62
        if self.storage.storing:
            raise Refuse(STATUS_ERROR[self.dialect])
        tokens = self.storage.values.get(int(params[0]))
        if tokens is None:
            raise Refuse(PARAMETER_ERROR[self.dialect])
        return ",".join(["AO", *tokens]), ()

    def sample_storage(self, now: float) -> None:
        """Take every reading due by ``now`` (on the serving thread)."""
        s = self.storage
        while s.storing:
            due = s.started_at + s.taken * s.cycle_s
            if due > now:
                return
            if now - due > s.cycle_s:
                s.late += 1
                s.worst_late_s = max(s.worst_late_s, now - due)
            for out in s.outs:
                try:
                    token, _ = self._display(out, due)
                except Exception:  # the source failed: that reading has no value
                    token = NO_VALUE
                s.values[out].append(token)
            if s.taken >= s.count:
                s.storing = False
