"""The errors of the PackML state machine (:mod:`cellctl.cell.packml`, which re-exports them)."""

from __future__ import annotations

from collections.abc import Iterable

from cellctl.domain import PackMLCommand, PackMLState, UnitMode


class PackMLError(Exception):
    """A request the state machine does not carry out."""


class CommandRefused(PackMLError):
    """A command was not carried out (the API answers 409; the PLC gets cmd_result 1, or 5 for an interlock)."""

    def __init__(self, state: PackMLState, command: PackMLCommand, reason: str) -> None:
        super().__init__(f"{command.name.title()} refused in {state.name.title()}: {reason}")
        self.state = state
        self.command = command
        self.reason = reason


class CommandNotAllowed(CommandRefused):
    """The transition table has no edge for this command in this state."""

    def __init__(self, state: PackMLState, command: PackMLCommand, allowed: Iterable[PackMLCommand]) -> None:
        self.allowed = tuple(sorted(allowed))
        names = ", ".join(c.name.title() for c in self.allowed) or "none"
        super().__init__(state, command, f"the PackML state model does not allow it (allowed here: {names})")


class CommandBlocked(CommandRefused):
    """The table allows the command, but an interlock (guard) holds it back, e.g. an active alarm."""


class ModeChangeNotAllowed(PackMLError):
    """A unit mode change outside the states that allow it (the API answers 409)."""

    def __init__(self, state: PackMLState, current: UnitMode, requested: UnitMode, allowed: Iterable[PackMLState]):
        names = ", ".join(s.name.title() for s in sorted(allowed))
        super().__init__(
            f"unit mode change {current.name.title()} -> {requested.name.title()} refused in "
            f"{state.name.title()}: modes change only in {names}"
        )
        self.state = state
        self.current = current
        self.requested = requested


class CycleStepNotAllowed(PackMLError):
    """A cycle step set outside Execute (steps are a sub-state of Execute)."""
