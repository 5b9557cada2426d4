"""How a cycle step reports that it cannot go on: the step, the alarm to raise and a readable reason."""

from __future__ import annotations

from cellctl.domain import AlarmCode, CycleStep


class CycleFailed(Exception):
    """A cycle stopped in ``step`` for ``reason``; ``code`` is the alarm to raise."""

    def __init__(self, step: CycleStep, code: AlarmCode, reason: str) -> None:
        super().__init__(f"{step.name.lower()}: {reason}")
        self.step = step
        self.code = code
        self.reason = reason
