"""What the simulated LK-G controller answers: the command set of both dialects and their rules.

:class:`LkgCommandSet` turns one command line into its reply (and the values it showed), keeping
the mode rules (measuring in general mode, settings in communication mode) and the settings the
PC wrote. The pseudo-terminal, the faults and the threads are cellctl's fake controller
(keyence_lkg.fake), which uses this class.
"""

from __future__ import annotations

import logging
import math
import re
import threading
from dataclasses import dataclass
from typing import Callable, Final, Literal, Protocol, Sequence, runtime_checkable

from cellctl.ports import LaserStatus
from keyence_lkg.errors import (
    COMMAND_ERROR,
    LENGTH_ERROR,
    OTHER_ERROR,
    PARAMETER_COUNT_ERROR,
    PARAMETER_ERROR,
    STATUS_ERROR,
    Dialect,
)
from keyence_lkg.fake_storage import Refuse, StorageCommands
from keyence_lkg.units import (
    NO_VALUE,
    OVER_RANGE_MINUS,
    OVER_RANGE_PLUS,
    UnitFormat,
    format_value,
    parse_setting_integer,
)

_log = logging.getLogger("keyence_lkg.fake")

DistanceSource = Callable[[], "float | None | LaserStatus"]


@runtime_checkable
class TimedSource(Protocol):
    """A distance source that can also say what it read at a past instant (s, time.monotonic()).

    The storage takes its readings from it at their exact instants, as the controller's own clock
    does, however late the fake's thread gets there.
    """

    def __call__(self) -> float | None | LaserStatus: ...

    def at(self, t: float) -> float | None | LaserStatus: ...
Mode = Literal["general", "communication"]
MAX_COMMAND_CHARS: Final = 64
Reply = tuple[str, tuple[float | None, ...]]
# The mode each mode command (Q0, R0) leaves the controller in.
_MODE_AFTER: Final[dict[str, Mode]] = {"Q0": "communication", "R0": "general"}


def _digit_in(n: int) -> Callable[[str], bool]:
    return lambda p: len(p) == 1 and p.isdigit() and int(p) < n


def _out_3001(p: str) -> bool:
    return p in ("1", "2")


def _out_5001(p: str) -> bool:
    return re.fullmatch(r"[0-9]{2}", p) is not None and 1 <= int(p) <= 12


def _setting_integer(p: str) -> bool:
    return re.fullmatch(r"[+-][0-9]{6}", p) is not None


@dataclass(frozen=True)
class _SettingSpec:
    address: tuple[Callable[[str], bool], ...]
    values: tuple[Callable[[str], bool], ...]
    default: tuple[str, ...]


def _digits(n: int) -> Callable[[str], bool]:
    return lambda p: re.fullmatch(f"[0-9]{{{n}}}", p) is not None


def setting_specs(dialect: Dialect) -> dict[str, _SettingSpec]:
    if dialect == "LK-G3001":
        return {
            "CA": _SettingSpec((), (_digit_in(6),), ("5",)),  # sampling cycle 20 us .. 1 ms
            # data storage: OUT, count, storage cycle code (keyence_lkg.storage)
            "CI": _SettingSpec((), (_out_3001, _digits(5), _digit_in(10)), ("1", "01000", "0")),
            "OC": _SettingSpec((_out_3001,), (lambda p: p == "0", _digit_in(10)), ("0", "0")),  # averaging
            "HB": _SettingSpec((_out_3001,), (_digit_in(5),), ("0",)),  # measurement mode
            "OF": _SettingSpec((_out_3001,), (_setting_integer,), ("+000000",)),  # offset
        }
    return {
        "CA": _SettingSpec((), (_digit_in(9),), ("8",)),  # sampling cycle 2.55 us .. 1 ms
        "CF": _SettingSpec((), (_digits(7), lambda p: _digits(2)(p) and int(p) < 10), ("0001000", "00")),  # storage: count, cycle
        "OK": _SettingSpec((_out_5001,), (_digit_in(2),), ("0",)),  # store this OUT (1) or not (0)
        "OC": _SettingSpec((_out_5001,), (lambda p: p == "0", _digit_in(10)), ("0", "0")),
        "HB": _SettingSpec((lambda p: p == "M", _out_5001), (_digit_in(5),), ("0",)),
        "OF": _SettingSpec((_out_5001,), (_setting_integer,), ("+000000",)),
    }


class LkgCommandSet(StorageCommands):
    """The controller's answers; the fake controller sets these attributes before serving."""

    dialect: Dialect
    mode: Mode
    setting_errors_name_the_setting: bool
    out_count: int
    unit: UnitFormat
    reference_distance_mm: float
    measuring_range_mm: float
    _sign: float
    _sources: dict[int, DistanceSource]
    _specs: dict[str, "_SettingSpec"]
    _settings: dict[tuple[str, tuple[str, ...]], tuple[str, ...]]
    _lock: threading.Lock


    @staticmethod
    def _main_of(text: str) -> str:
        main = text.split(",", 1)[0].upper()
        return "".join(c if " " <= c <= "~" else "?" for c in main)

    def _handle(self, text: str) -> tuple[str, tuple[float | None, ...]]:
        main = self._main_of(text)
        params = [p.upper() for p in text.split(",")[1:]]
        d = self.dialect
        try:
            if len(text) > MAX_COMMAND_CHARS or len(main) != 2:
                raise Refuse(LENGTH_ERROR[d])
            handler = self._handlers().get(main)
            if handler is None:
                raise Refuse(COMMAND_ERROR[d])
            needs, run = handler
            with self._lock:
                mode = self.mode
            if needs == "general" and mode != "general":
                raise Refuse(STATUS_ERROR[d])
            if needs == "communication" and mode != "communication":
                raise Refuse(STATUS_ERROR[d])
            return run(main, params)
        except Refuse as refusal:
            header = main
            if self.setting_errors_name_the_setting and main in ("SW", "SR") and params:
                header = params[0]  # as the ISIS emulator answers: ER,OF,00 for SW,OF,...
            return f"ER,{header},{refusal.code}", ()

    def _handlers(self) -> dict[str, tuple[str, Callable[[str, list[str]], tuple[str, tuple[float | None, ...]]]]]:
        common = {
            "Q0": ("any", self._switch_mode),
            "R0": ("any", self._switch_mode),
            "SW": ("communication", self._sw),
            "SR": ("communication", self._sr),
            **{m: ("general", h) for m, h in (("AQ", self._aq), ("AS", self._as), ("AP", self._ap), ("AN", self._an), ("AO", self._ao))},
        }
        if self.dialect == "LK-G3001":
            return {"M0": ("general", self._m0), "M1": ("general", self._m12), "M2": ("general", self._m12), **common}
        return {"MS": ("general", self._ms), "MM": ("general", self._mm), "MA": ("general", self._ma), **common}

    def _no_params(self, params: Sequence[str]) -> None:
        if params:
            raise Refuse(PARAMETER_COUNT_ERROR[self.dialect])

    def _switch_mode(self, main: str, params: list[str]) -> tuple[str, tuple[float | None, ...]]:
        """Q0 enters communication mode, R0 returns to general mode; refused when already there."""
        self._no_params(params)
        target = _MODE_AFTER[main]
        with self._lock:
            if self.mode == target:
                raise Refuse(STATUS_ERROR[self.dialect])
            self.mode = target
        return main, ()

    def _values(self, main_echo: str, outs: Sequence[int]) -> tuple[str, tuple[float | None, ...]]:
        tokens, shown = [], []
        for out in outs:
            token, mm = self._display(out)
            tokens.append(token)
            shown.append(mm)
        return ",".join([main_echo, *tokens]), tuple(shown)

    def _m0(self, main: str, params: list[str]) -> tuple[str, tuple[float | None, ...]]:
        self._no_params(params)
        return self._values("M0", (1, 2))

    def _m12(self, main: str, params: list[str]) -> tuple[str, tuple[float | None, ...]]:
        self._no_params(params)
        return self._values(main, (int(main[1]),))

    def _ms(self, main: str, params: list[str]) -> tuple[str, tuple[float | None, ...]]:
        if len(params) != 1:
            raise Refuse(PARAMETER_COUNT_ERROR[self.dialect])
        if not _out_5001(params[0]):
            raise Refuse(PARAMETER_ERROR[self.dialect])
        return self._values(f"MS,{params[0]}", (int(params[0]),))

    def _mm(self, main: str, params: list[str]) -> tuple[str, tuple[float | None, ...]]:
        if len(params) != 1:
            raise Refuse(PARAMETER_COUNT_ERROR[self.dialect])
        mask = params[0]
        if re.fullmatch(r"[01]{12}", mask) is None or "1" not in mask:
            raise Refuse(PARAMETER_ERROR[self.dialect])
        return self._values(f"MM,{mask}", [i + 1 for i, c in enumerate(mask) if c == "1"])

    def _ma(self, main: str, params: list[str]) -> tuple[str, tuple[float | None, ...]]:
        self._no_params(params)
        return self._values("MA", range(1, self.out_count + 1))

    def _sw(self, main: str, params: list[str]) -> tuple[str, tuple[float | None, ...]]:
        ident, spec, address, values = self._setting_args(params, write=True)
        with self._lock:
            self._settings[(ident, address)] = values
        return f"SW,{ident}", ()

    def _sr(self, main: str, params: list[str]) -> tuple[str, tuple[float | None, ...]]:
        ident, spec, address, _ = self._setting_args(params, write=False)
        with self._lock:
            values = self._settings.get((ident, address), spec.default)
        if ident == "OF":  # the setting check format: sign, six digits and a decimal point
            values = (format_value(parse_setting_integer(values[0], self.unit), self.unit),)
        return ",".join(("SR", ident, *address, *values)), ()

    def _setting_args(
        self, params: list[str], *, write: bool
    ) -> tuple[str, _SettingSpec, tuple[str, ...], tuple[str, ...]]:
        if not params:
            raise Refuse(PARAMETER_COUNT_ERROR[self.dialect])
        ident, rest = params[0], params[1:]
        spec = self._specs.get(ident)
        if spec is None:
            raise Refuse(PARAMETER_ERROR[self.dialect])
        n_addr = len(spec.address)
        expected = n_addr + (len(spec.values) if write else 0)
        if len(rest) != expected:
            raise Refuse(PARAMETER_COUNT_ERROR[self.dialect])
        checks = spec.address + (spec.values if write else ())
        if not all(check(p) for check, p in zip(checks, rest, strict=True)):
            raise Refuse(PARAMETER_ERROR[self.dialect])
        return ident, spec, tuple(rest[:n_addr]), tuple(rest[n_addr:])

    def _setting_of(self, ident: str, address: tuple[str, ...]) -> tuple[str, ...]:
        """A setting's value: what the PC wrote, else the controller's default."""
        with self._lock:
            return self._settings.get((ident, address), self._specs[ident].default)

    def _offset_mm(self, out: int) -> float:
        key = ("OF", (f"{out:0{1 if self.dialect == 'LK-G3001' else 2}d}",))
        with self._lock:
            stored = self._settings.get(key)
        return parse_setting_integer(stored[0], self.unit) if stored else 0.0

    def _display(self, out: int, at: float | None = None) -> tuple[str, float | None]:
        """The token an OUT shows now (or at instant ``at`` of time.monotonic(), where its source can
        say: a ``TimedSource``), and its value in mm (None for the special tokens)."""
        source = self._sources.get(out)
        if source is None or out > self.out_count:
            return NO_VALUE, None
        try:
            distance = source.at(at) if at is not None and isinstance(source, TimedSource) else source()
        except Exception:  # the physics callback failed: the controller reports "other error"
            _log.exception("fake LK-G: distance callback of OUT%d raised", out)
            raise Refuse(OTHER_ERROR) from None
        far = OVER_RANGE_PLUS if self._sign > 0 else OVER_RANGE_MINUS
        near = OVER_RANGE_MINUS if self._sign > 0 else OVER_RANGE_PLUS
        if distance is None or distance is LaserStatus.OVER_RANGE_FAR:
            return far, None
        if distance is LaserStatus.OVER_RANGE_NEAR:
            return near, None
        if distance is LaserStatus.NO_VALUE:
            return NO_VALUE, None
        if isinstance(distance, LaserStatus) or not isinstance(distance, (int, float)) or not math.isfinite(distance):
            _log.error("fake LK-G: distance callback of OUT%d returned %r", out, distance)
            raise Refuse(OTHER_ERROR)
        displacement = self._sign * (float(distance) - self.reference_distance_mm)
        if abs(displacement) > self.measuring_range_mm:
            return (OVER_RANGE_PLUS if displacement > 0 else OVER_RANGE_MINUS), None
        token = format_value(displacement + self._offset_mm(out), self.unit)
        if token in (OVER_RANGE_PLUS, OVER_RANGE_MINUS):
            return token, None
        return token, float(token) * self.unit.mm_per_unit
