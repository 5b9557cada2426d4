"""Operator prompts: a commissioning job pauses until the engineer confirms, cancels or gives a value.

A prompt has a ``kind`` (what is asked, in words a program can act on: the CLI, the dashboard
and the simulated cell's operator all read it) and a ``text`` for the engineer. The service's
:class:`PromptDesk` publishes each open prompt on the event stream and waits for an answer from
REST (``POST /jobs/{id}/prompts/{prompt_id}``); a job cancelled while it waits closes its prompt.
"""

from __future__ import annotations

import asyncio
import enum
import functools
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any, Literal, Protocol


class PromptKind(str, enum.Enum):
    """What a prompt asks the engineer to do before the job goes on."""

    CAR_BODY = "car_body_in_place"  # a car body (the reference one for teaching) stands clamped in the cell
    PLACE_BOARD = "place_board"  # stick the checkerboard on the wall at the given place; give its measured square
    REMOVE_BOARD = "remove_board"  # take the board off the wall
    CONFIRM_START = "confirm_start"  # the plan is shown: confirm the path to the first pose is clear
    GUIDE_INSTALL = "guide_install"  # jog or lead the robot until the glass sits in the opening
    RETREAT = "retreat"  # jog the robot back out of the opening to a clear pose


# What each prompt asks of the engineer, and what answers it takes (the docs table is made from this).
PROMPT_MEANINGS: dict[PromptKind, tuple[str, str]] = {
    PromptKind.CAR_BODY: ("a car body stands clamped in the cell (for teaching: the reference car body at its nominal place)", "confirm or cancel"),
    PromptKind.PLACE_BOARD: ("stick the checkerboard flat on the wall at the given place; measure its square size", "the measured square size in mm (confirm keeps the nominal), or cancel"),
    PromptKind.REMOVE_BOARD: ("take the board off the wall", "confirm or cancel"),
    PromptKind.CONFIRM_START: ("the plan is shown (poses, robot time, the first pose): check that the way to the first pose is clear", "confirm or cancel"),
    PromptKind.GUIDE_INSTALL: ("jog or lead the robot until the glass sits in the opening as it must be installed; the pose is read from the robot", "confirm or cancel"),
    PromptKind.RETREAT: ("jog the robot with the glass back out of the opening to a clear pose", "confirm or cancel"),
}

AnswerAction = Literal["confirm", "cancel", "value"]


@dataclass(frozen=True)
class Prompt:
    """One question to the engineer.

    Attributes:
        id: unique in the service's run.
        job_id: the job that asks.
        kind: what is asked (:class:`PromptKind`).
        text: what the engineer reads.
        details: figures that go with it (where the board goes, the first pose, ...), JSON-ready.
        value_label: when a value may be given with the confirmation: what it is, with its unit.
        default: the value taken when the engineer confirms without giving one.
        created_utc: when it was asked.
    """

    id: int
    job_id: int
    kind: PromptKind
    text: str
    details: dict[str, Any] = field(default_factory=dict)
    value_label: str | None = None
    default: float | None = None
    created_utc: str = ""

    def as_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "job_id": self.job_id,
            "kind": self.kind.value,
            "text": self.text,
            "details": self.details,
            "value_label": self.value_label,
            "default": self.default,
            "created_utc": self.created_utc,
        }


@dataclass(frozen=True)
class Answer:
    """The engineer's answer: ``confirm``, ``cancel``, or ``value`` (a confirmation with a number)."""

    action: AnswerAction
    value: float | None = None
    actor: str = "unknown"
    source: str = "unknown"


class PromptCancelled(Exception):
    """The engineer answered a prompt with cancel."""

    def __init__(self, prompt: Prompt, actor: str) -> None:
        super().__init__(f"cancelled by {actor} at the prompt '{prompt.kind.value}'")
        self.prompt = prompt
        self.actor = actor


class PromptError(ValueError):
    """An answer the desk cannot take; the message says why and what to send instead."""


class UnknownPrompt(PromptError):
    """No open prompt with that id (answered already, or its job ended)."""


class Ask(Protocol):
    """What a procedure calls to pause for the engineer; returns the answer (never ``cancel``)."""

    async def __call__(
        self,
        kind: PromptKind,
        text: str,
        *,
        details: dict[str, Any] | None = None,
        value_label: str | None = None,
        default: float | None = None,
    ) -> Answer: ...


Publish = Callable[[str, dict[str, Any]], object]


class PromptDesk:
    """The open prompts of the running service; answers come from REST (or the simulated operator)."""

    def __init__(self, publish: Publish) -> None:
        self._publish = publish
        self._ids = itertools.count(1)
        self._open: dict[int, tuple[Prompt, asyncio.Future[Answer]]] = {}
        self._watchers: list[Callable[[Prompt], None]] = []

    def watch(self, callback: Callable[[Prompt], None]) -> Callable[[], None]:
        """Call ``callback`` with every new prompt (the simulated operator listens here); returns the undo."""
        self._watchers.append(callback)
        return lambda: self._watchers.remove(callback)

    def open_prompts(self, job_id: int | None = None) -> list[Prompt]:
        return [p for p, _ in self._open.values() if job_id is None or p.job_id == job_id]

    def asker(self, job_id: int) -> Ask:
        """The ``ask`` a job's procedures use: :meth:`ask` bound to the job."""
        return functools.partial(self.ask, job_id)

    async def ask(
        self,
        job_id: int,
        kind: PromptKind,
        text: str,
        *,
        details: dict[str, Any] | None = None,
        value_label: str | None = None,
        default: float | None = None,
    ) -> Answer:
        """Open a prompt and wait for its answer; raises PromptCancelled on ``cancel``."""
        prompt = Prompt(
            next(self._ids), job_id, PromptKind(kind), text, dict(details or {}), value_label, default,
            datetime.now(timezone.utc).isoformat(),
        )  # fmt: skip
        future: asyncio.Future[Answer] = asyncio.get_running_loop().create_future()
        self._open[prompt.id] = (prompt, future)
        self._publish("prompt", {"job_id": job_id, "open": True, "prompt": prompt.as_dict()})
        for watcher in list(self._watchers):
            watcher(prompt)
        try:
            answer = await future
        except asyncio.CancelledError:  # the job ended while it waited: the prompt closes unanswered
            self._publish("prompt", {"job_id": job_id, "open": False, "prompt": prompt.as_dict(), "answer": None})
            raise
        finally:
            self._open.pop(prompt.id, None)
        self._publish(
            "prompt",
            {"job_id": job_id, "open": False, "prompt": prompt.as_dict(),
             "answer": {"action": answer.action, "value": answer.value, "actor": answer.actor, "source": answer.source}},
        )  # fmt: skip
        if answer.action == "cancel":
            raise PromptCancelled(prompt, answer.actor)
        return answer

    def answer(self, prompt_id: int, answer: Answer, *, job_id: int | None = None) -> Prompt:
        """Answer an open prompt. A ``value`` answer needs a finite number and a prompt that asks for one."""
        entry = self._open.get(prompt_id)
        if entry is None or (job_id is not None and entry[0].job_id != job_id):
            raise UnknownPrompt(f"no open prompt {prompt_id}" + (f" of job {job_id}" if job_id is not None else "")
                                + "; it was answered already or its job has ended (GET /jobs/{id} shows the open one)")  # fmt: skip
        prompt, future = entry
        if answer.action not in ("confirm", "cancel", "value"):
            raise PromptError(f"action must be 'confirm', 'cancel' or 'value', got {answer.action!r}")
        if answer.action == "value":
            if prompt.value_label is None:
                raise PromptError(f"prompt {prompt_id} ({prompt.kind.value}) asks for no value: answer 'confirm' or 'cancel'")
            if answer.value is None or not math.isfinite(answer.value) or answer.value <= 0:
                raise PromptError(f"value: give a positive number for '{prompt.value_label}', got {answer.value!r}")
        if answer.action == "confirm" and prompt.value_label is not None and prompt.default is not None:
            answer = Answer("value", prompt.default, answer.actor, answer.source)
        if not future.done():
            future.set_result(answer)
        return prompt
