"""The PackML state machine of the cell (ANSI/ISA-TR88.00.02, PackTags v3.0 integers).

:data:`TRANSITIONS` is the single source of truth: every commanded edge ``(state, command) ->
next state`` and every state-complete (SC) edge of an acting state. The machine, the REST API's
409, the dashboard's greyed buttons and ``docs/packml_states.md`` are all derived from it. One
exception leaves the table and the state alone: a taker (:meth:`PackMLMachine.add_taker`) may carry
out a command with no edge, e.g. a Stop in Stopped that cancels a running commissioning job.

Structure (OPC 30050): Aborting and Aborted sit outside the *Cleared* superstate; Clearing,
Stopped, Stopping and the *Running* sub-machine sit inside it. Abort is accepted from any state
inside Cleared, Stop from any Running sub-state. The cycle's steps (calibrate, align, shoot,
compensate, install) are a sub-state of Execute: :class:`~cellctl.cell.tags.CycleStep`.

Unit modes (Production, Maintenance, Manual) may change only in the states of
``mode_change_states`` (by default Stopped, Idle and Aborted).

The machine's events (:class:`~cellctl.domain.MachineEvent`) and the enumerations are plain
values of :mod:`cellctl.domain` (the store keeps them too); they are re-exported here.
``docs/packml_states.md`` is rendered from this table by :mod:`cellctl.cell.packml_doc`.
"""

from __future__ import annotations

import asyncio
import enum
from collections.abc import Awaitable, Callable, Iterable, Mapping
from dataclasses import dataclass, fields
from datetime import datetime, timezone
from types import MappingProxyType

from cellctl.cell.observers import Fanout
from cellctl.cell.packml_errors import CommandBlocked as CommandBlocked
from cellctl.cell.packml_errors import CommandNotAllowed as CommandNotAllowed
from cellctl.cell.packml_errors import CommandRefused as CommandRefused
from cellctl.cell.packml_errors import CycleStepNotAllowed as CycleStepNotAllowed
from cellctl.cell.packml_errors import ModeChangeNotAllowed as ModeChangeNotAllowed
from cellctl.cell.packml_errors import PackMLError as PackMLError
from cellctl.domain import CycleStep, PackMLCommand, PackMLState, UnitMode
from cellctl.domain import EventKind as EventKind  # re-exported: the machine's events
from cellctl.domain import MachineEvent as MachineEvent

S = PackMLState
C = PackMLCommand


class Trigger(enum.Enum):
    """What fires an edge that is not a command: the acting state's work is done."""

    STATE_COMPLETE = "SC"


EdgeTrigger = PackMLCommand | Trigger


@dataclass(frozen=True)
class Transition:
    """One edge of the state model."""

    source: PackMLState
    trigger: EdgeTrigger
    target: PackMLState


# --- The state model's sets (OPC 30050 section 6.3.5) -------------------------------------------

RUNNING_STATES: frozenset[PackMLState] = frozenset(
    {
        S.RESETTING, S.IDLE, S.STARTING, S.EXECUTE, S.COMPLETING, S.COMPLETE,
        S.SUSPENDING, S.SUSPENDED, S.UNSUSPENDING, S.HOLDING, S.HELD, S.UNHOLDING,
    }
)  # fmt: skip
"""Sub-states of Running: Stop is accepted from each of them."""

CLEARED_STATES: frozenset[PackMLState] = RUNNING_STATES | {S.CLEARING, S.STOPPED, S.STOPPING}
"""Sub-states of Cleared: Abort is accepted from each of them."""

ACTING_STATES: frozenset[PackMLState] = frozenset(
    {
        S.CLEARING, S.STARTING, S.STOPPING, S.ABORTING, S.HOLDING, S.UNHOLDING,
        S.SUSPENDING, S.UNSUSPENDING, S.RESETTING, S.COMPLETING,
    }
)  # fmt: skip
"""States that do work and leave by SC (their names end in -ing)."""

WAIT_STATES: frozenset[PackMLState] = frozenset(
    {S.IDLE, S.HELD, S.SUSPENDED, S.COMPLETE, S.STOPPED, S.ABORTED}
)
"""States that wait for a command."""

CYCLE_STATES: frozenset[PackMLState] = frozenset(
    {S.EXECUTE, S.HOLDING, S.HELD, S.UNHOLDING, S.SUSPENDING, S.SUSPENDED, S.UNSUSPENDING}
)
"""States in which a cycle step is kept: Execute and its paused variants (Hold and Suspend
return to Execute, so the step survives them). Entering any other state resets it to NONE."""

DEFAULT_MODE_CHANGE_STATES: frozenset[PackMLState] = frozenset({S.STOPPED, S.IDLE, S.ABORTED})

INITIAL_STATES: frozenset[PackMLState] = frozenset({S.ABORTED, S.STOPPED})
"""OPC 30050 lets a machine start in Aborted or in Stopped; never in Execute."""


def _build_transitions() -> tuple[Transition, ...]:
    edges: list[Transition] = [
        Transition(S.STOPPED, C.RESET, S.RESETTING),
        Transition(S.COMPLETE, C.RESET, S.RESETTING),
        Transition(S.IDLE, C.START, S.STARTING),
        Transition(S.EXECUTE, C.COMPLETE, S.COMPLETING),
        Transition(S.EXECUTE, C.HOLD, S.HOLDING),
        Transition(S.HELD, C.UNHOLD, S.UNHOLDING),
        Transition(S.EXECUTE, C.SUSPEND, S.SUSPENDING),
        Transition(S.SUSPENDED, C.UNSUSPEND, S.UNSUSPENDING),
        Transition(S.ABORTED, C.CLEAR, S.CLEARING),
    ]
    edges += [Transition(s, C.STOP, S.STOPPING) for s in sorted(RUNNING_STATES)]
    edges += [Transition(s, C.ABORT, S.ABORTING) for s in sorted(CLEARED_STATES)]
    sc = Trigger.STATE_COMPLETE
    edges += [
        Transition(S.RESETTING, sc, S.IDLE),
        Transition(S.STARTING, sc, S.EXECUTE),
        Transition(S.EXECUTE, sc, S.COMPLETING),
        Transition(S.COMPLETING, sc, S.COMPLETE),
        Transition(S.HOLDING, sc, S.HELD),
        Transition(S.UNHOLDING, sc, S.EXECUTE),
        Transition(S.SUSPENDING, sc, S.SUSPENDED),
        Transition(S.UNSUSPENDING, sc, S.EXECUTE),
        Transition(S.STOPPING, sc, S.STOPPED),
        Transition(S.ABORTING, sc, S.ABORTED),
        Transition(S.CLEARING, sc, S.STOPPED),
    ]
    return tuple(edges)


TRANSITIONS: tuple[Transition, ...] = _build_transitions()
"""THE transition table. Everything below is derived from it."""


def _index(edges: Iterable[Transition]) -> tuple[
    Mapping[tuple[PackMLState, PackMLCommand], PackMLState], Mapping[PackMLState, PackMLState]
]:
    commanded: dict[tuple[PackMLState, PackMLCommand], PackMLState] = {}
    complete: dict[PackMLState, PackMLState] = {}
    for e in edges:
        if isinstance(e.trigger, PackMLCommand):
            key = (e.source, e.trigger)
            if key in commanded:
                raise ValueError(f"transition table has two edges for {e.source.name} + {e.trigger.name}")
            commanded[key] = e.target
        else:
            if e.source in complete:
                raise ValueError(f"transition table has two SC edges from {e.source.name}")
            complete[e.source] = e.target
    return MappingProxyType(commanded), MappingProxyType(complete)


COMMANDED, STATE_COMPLETE = _index(TRANSITIONS)
"""``COMMANDED[(state, command)] -> next state``; ``STATE_COMPLETE[state] -> next state``."""


def next_state(state: PackMLState, command: PackMLCommand) -> PackMLState | None:
    """Where ``command`` takes the machine from ``state``, or None if the table forbids it."""
    return COMMANDED.get((state, command))


def commands_allowed_in(state: PackMLState) -> frozenset[PackMLCommand]:
    """The commands the table accepts in ``state``."""
    return frozenset(c for (s, c) in COMMANDED if s == state)


# --- Errors (the others are in :mod:`cellctl.cell.packml_errors`) ------------------------------


class StateCompleteNotAllowed(PackMLError):
    """``state_complete()`` in a state that has no SC edge (a wait state)."""

    def __init__(self, state: PackMLState) -> None:
        super().__init__(
            f"state complete (SC) is not defined for {state.name.title()}: only acting states and Execute "
            f"finish by SC ({', '.join(s.name.title() for s in sorted(STATE_COMPLETE))})"
        )
        self.state = state


# --- Snapshots -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class MachineStatus:
    """A consistent snapshot for /status, the dashboard and the PLC's status block."""

    state: PackMLState
    mode: UnitMode
    cycle_step: CycleStep
    allowed_commands: frozenset[PackMLCommand]
    blocked_commands: Mapping[PackMLCommand, str]
    mode_change_allowed: bool
    state_since: datetime
    seq: int


Guard = Callable[[PackMLState, PackMLCommand], "str | None"]
"""An interlock: returns a reason to refuse the command, or None to let it through. Must be fast
and must not block (it runs under the machine's lock and for every ``allowed_commands()``)."""

TakenAction = Callable[[str, str], Awaitable[str]]
"""Carries out a taken command for ``(actor, source)`` once the machine's lock is released (the state
stays); returns what it did, for the answer and the log. It must not raise for a normal outcome."""

Taker = Callable[[PackMLState, PackMLCommand], "TakenAction | None"]
"""Takes a command the table has no edge for in this state: returns the action that carries it out, or
None to leave it refused. Fast and non-blocking, like a guard."""


@dataclass(frozen=True)
class TakenCommand(MachineEvent):
    """What :meth:`PackMLMachine.command` returns for a command a taker carried out: the event (the state
    stays) and ``effect``, what the taker did (e.g. the commissioning job a Stop in Stopped cancelled)."""

    effect: str = ""


Observer = Callable[[MachineEvent], object]


def _utcnow() -> datetime:
    return datetime.now(timezone.utc)


# --- The machine ---------------------------------------------------------------------------------


class PackMLMachine:
    """The cell's PackML state machine: one writer (an asyncio lock), observers told of every change.

    Observers: ``subscribe(callback)`` calls a plain function with each :class:`MachineEvent`
    synchronously, in order, under the lock (a callback must not block; to act, e.g. issue a
    command, it schedules a task). ``subscribe_queue()`` hands out an asyncio queue fed in order.
    An exception in a callback is logged and does not stop the machine or the other observers.

    Takers (``add_taker``) carry out a command the table has no edge for in the current state without
    leaving it (e.g. Stop in Stopped cancels a running commissioning job); the table is unchanged.

    Args:
        initial_state: Aborted (default) or Stopped; after a restart the cell never resumes running.
        initial_mode: the unit mode at start.
        mode_change_states: the states in which the unit mode may change.
        clock: UTC wall clock for event times.
    """

    def __init__(
        self,
        *,
        initial_state: PackMLState = S.ABORTED,
        initial_mode: UnitMode = UnitMode.PRODUCTION,
        mode_change_states: Iterable[PackMLState] = DEFAULT_MODE_CHANGE_STATES,
        clock: Callable[[], datetime] = _utcnow,
    ) -> None:
        initial_state = PackMLState(initial_state)
        if initial_state not in INITIAL_STATES:
            raise ValueError(
                f"initial_state {initial_state.name} is not allowed: the cell starts in "
                f"{' or '.join(s.name for s in sorted(INITIAL_STATES))}, never in a running state"
            )
        initial_mode = UnitMode(initial_mode)
        if initial_mode == UnitMode.INVALID:
            raise ValueError("initial_mode must be PRODUCTION, MAINTENANCE or MANUAL, not INVALID")
        states = frozenset(PackMLState(s) for s in mode_change_states)
        if not states or S.UNDEFINED in states:
            raise ValueError(
                "mode_change_states must be a non-empty set of defined PackML states "
                f"(e.g. Stopped, Idle, Aborted), got {sorted(s.name for s in states)}"
            )
        self.mode_change_states: frozenset[PackMLState] = states
        self._clock = clock
        self._state = initial_state
        self._mode = initial_mode
        self._step = CycleStep.NONE
        self._seq = 0
        self._since = clock()
        self._lock = asyncio.Lock()
        self._changed = asyncio.Condition()
        self._guards: dict[PackMLCommand, list[Guard]] = {}
        self._takers: dict[PackMLCommand, list[Taker]] = {}
        self._events: Fanout[MachineEvent] = Fanout("PackML")

    # -- reading ------------------------------------------------------------------------------

    @property
    def state(self) -> PackMLState:
        return self._state

    @property
    def mode(self) -> UnitMode:
        return self._mode

    @property
    def cycle_step(self) -> CycleStep:
        return self._step

    def blocked_commands(self) -> dict[PackMLCommand, str]:
        """Table-allowed commands that a guard holds back now, with the guard's reason."""
        out: dict[PackMLCommand, str] = {}
        for cmd in commands_allowed_in(self._state):
            reason = self._guard_reason(cmd)
            if reason is not None:
                out[cmd] = reason
        return out

    def taken_commands(self) -> frozenset[PackMLCommand]:
        """Commands the table has no edge for here that a taker would carry out now."""
        table = commands_allowed_in(self._state)
        return frozenset(c for c in self._takers if c not in table and self._taken(c) is not None)

    def allowed_commands(self) -> frozenset[PackMLCommand]:
        """The commands that would be carried out now (a table edge no guard objects to, or a taker's)."""
        return commands_allowed_in(self._state) - self.blocked_commands().keys() | self.taken_commands()

    def mode_change_allowed(self) -> bool:
        return self._state in self.mode_change_states

    def status(self) -> MachineStatus:
        blocked = self.blocked_commands()
        return MachineStatus(
            state=self._state,
            mode=self._mode,
            cycle_step=self._step,
            allowed_commands=commands_allowed_in(self._state) - blocked.keys() | self.taken_commands(),
            blocked_commands=MappingProxyType(blocked),
            mode_change_allowed=self.mode_change_allowed(),
            state_since=self._since,
            seq=self._seq,
        )

    # -- guards and observers -----------------------------------------------------------------

    def add_guard(self, command: PackMLCommand, guard: Guard) -> None:
        """Add an interlock on ``command`` (checked after the table allows it)."""
        self._guards.setdefault(PackMLCommand(command), []).append(guard)

    def add_taker(self, command: PackMLCommand, taker: Taker) -> None:
        """Let ``taker`` carry out ``command`` where the table has no edge for it (asked only there)."""
        self._takers.setdefault(PackMLCommand(command), []).append(taker)

    def subscribe(self, callback: Observer) -> Callable[[], None]:
        """Call ``callback(event)`` on every change; returns a function that unsubscribes."""
        return self._events.subscribe(callback)

    def subscribe_queue(self, maxsize: int = 0) -> asyncio.Queue[MachineEvent]:
        """An asyncio queue receiving every event. With ``maxsize`` > 0 a full queue drops its
        oldest event (a slow dashboard must not stall the cell); unbounded by default."""
        return self._events.subscribe_queue(maxsize)

    def unsubscribe_queue(self, queue: asyncio.Queue[MachineEvent]) -> None:
        self._events.unsubscribe_queue(queue)

    # -- changing -----------------------------------------------------------------------------

    async def command(self, command: PackMLCommand | int, *, actor: str, source: str) -> MachineEvent:
        """Carry out ``command``; raises CommandNotAllowed or CommandBlocked (both CommandRefused).

        ``actor`` says who (user name, ``plc``, ``system``), ``source`` from where (client
        address, ``modbus``, ``alarm:<code>``); both go into the event for the audit log.
        Where the table has no edge a taker may carry it out: its event (the state stays) is
        published, then its action runs outside the lock; the answer is a :class:`TakenCommand`.
        """
        cmd = self._as_command(command)
        async with self._lock:
            target = next_state(self._state, cmd)
            if target is not None:
                reason = self._guard_reason(cmd)
                if reason is not None:
                    raise CommandBlocked(self._state, cmd, reason)
                return await self._move(EventKind.COMMAND, target, actor, source, cmd)
            action = self._taken(cmd)
            if action is None:
                raise CommandNotAllowed(self._state, cmd, commands_allowed_in(self._state))
            ev = await self._emit(EventKind.COMMAND, self._state, self._state, self._mode, self._step, actor, source, cmd)
        effect = await action(actor, source)
        return TakenCommand(**{f.name: getattr(ev, f.name) for f in fields(ev)}, effect=effect)

    async def state_complete(self, *, actor: str = "system", source: str = "cell") -> MachineEvent:
        """The acting state's work is done (SC): follow its SC edge."""
        async with self._lock:
            target = STATE_COMPLETE.get(self._state)
            if target is None:
                raise StateCompleteNotAllowed(self._state)
            return await self._move(EventKind.STATE_COMPLETE, target, actor, source, None)

    async def change_mode(self, mode: UnitMode | int, *, actor: str, source: str) -> MachineEvent:
        """Switch the unit mode; only in ``mode_change_states`` (asking for the mode it is in is no change: taken anywhere)."""
        try:
            new = UnitMode(mode)
        except ValueError:
            raise ValueError(f"unknown unit mode {mode!r}: use 1 (Production), 2 (Maintenance) or 3 (Manual)") from None
        if new == UnitMode.INVALID:
            raise ValueError("unit mode 0 (Invalid) cannot be requested: use 1, 2 or 3")
        async with self._lock:
            if self._state not in self.mode_change_states and new != self._mode:
                raise ModeChangeNotAllowed(self._state, self._mode, new, self.mode_change_states)
            before = self._mode
            self._mode = new
            return await self._emit(EventKind.MODE, self._state, self._state, before, self._step, actor, source, None)

    async def set_cycle_step(self, step: CycleStep | int, *, actor: str = "system", source: str = "cell") -> MachineEvent:
        """Enter a cycle step. Real steps only in Execute; NONE (cycle done) in any cycle state."""
        new = CycleStep(step)
        async with self._lock:
            if new != CycleStep.NONE and self._state != S.EXECUTE:
                raise CycleStepNotAllowed(
                    f"cycle step {new.name.lower()} needs Execute; the machine is in {self._state.name.title()}"
                )
            if new == CycleStep.NONE and self._state not in CYCLE_STATES:
                raise CycleStepNotAllowed(
                    f"no cycle runs in {self._state.name.title()}; the step is already none"
                )
            return await self._emit(
                EventKind.CYCLE_STEP, self._state, self._state, self._mode, self._step, actor, source, None, new
            )

    async def wait_for_state(self, *states: PackMLState, timeout_s: float) -> PackMLState:
        """Wait until the machine is in one of ``states``; raises TimeoutError after ``timeout_s``."""
        want = frozenset(states)
        async with self._changed:
            await asyncio.wait_for(self._changed.wait_for(lambda: self._state in want), timeout_s)
        return self._state

    # -- internals ----------------------------------------------------------------------------

    @staticmethod
    def _as_command(command: PackMLCommand | int) -> PackMLCommand:
        try:
            return PackMLCommand(command)
        except ValueError:
            raise ValueError(
                f"unknown PackML command {command!r}: use 1..10 "
                f"({', '.join(f'{c.value} {c.name.title()}' for c in PackMLCommand if c)})"
            ) from None

    def _guard_reason(self, cmd: PackMLCommand) -> str | None:
        return next((r for g in self._guards.get(cmd, ()) if (r := g(self._state, cmd)) is not None), None)

    def _taken(self, cmd: PackMLCommand) -> TakenAction | None:
        return next((a for t in self._takers.get(cmd, ()) if (a := t(self._state, cmd)) is not None), None)

    async def _move(
        self, kind: EventKind, target: PackMLState, actor: str, source: str, cmd: PackMLCommand | None
    ) -> MachineEvent:
        before = self._state
        step_before = self._step
        self._state = target
        self._since = self._clock()
        step_after = step_before if target in CYCLE_STATES else CycleStep.NONE
        return await self._emit(kind, before, target, self._mode, step_before, actor, source, cmd, step_after)

    async def _emit(
        self,
        kind: EventKind,
        state_before: PackMLState,
        state_after: PackMLState,
        mode_before: UnitMode,
        step_before: CycleStep,
        actor: str,
        source: str,
        cmd: PackMLCommand | None,
        step_after: CycleStep | None = None,
    ) -> MachineEvent:
        self._seq += 1
        if step_after is not None:
            self._step = step_after
        event = MachineEvent(
            seq=self._seq,
            kind=kind,
            at=self._clock(),
            actor=actor,
            source=source,
            state_before=state_before,
            state_after=state_after,
            mode_before=mode_before,
            mode_after=self._mode,
            step_before=step_before,
            step_after=self._step,
            command=cmd,
        )
        self._events.publish(event)
        async with self._changed:
            self._changed.notify_all()
        return event
