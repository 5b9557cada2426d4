"""The PackML state model as Markdown: ``docs/packml_states.md``, rendered from the transition table.

Everything in the document is derived from :mod:`cellctl.cell.packml` (the table and the state
sets) and the enumerations of :mod:`cellctl.domain`; a test keeps the committed file equal to it.

Regenerate the docs with ``python -m cellctl.cell.packml_doc -o docs/packml_states.md``.
"""

from __future__ import annotations

from collections.abc import Iterable

from cellctl.cell.packml import (
    ACTING_STATES,
    CLEARED_STATES,
    COMMANDED,
    CYCLE_STATES,
    DEFAULT_MODE_CHANGE_STATES,
    RUNNING_STATES,
    STATE_COMPLETE,
    TRANSITIONS,
    WAIT_STATES,
    Trigger,
)
from cellctl.domain import CycleStep, PackMLCommand, PackMLState, UnitMode
from cellctl.markdown_doc import markdown_doc_main

S = PackMLState
C = PackMLCommand


def _t(x: PackMLState | PackMLCommand | UnitMode) -> str:
    return x.name.title()


def render_markdown(mode_change_states: Iterable[PackMLState] = DEFAULT_MODE_CHANGE_STATES) -> str:
    """The state model as Markdown, generated from :data:`~cellctl.cell.packml.TRANSITIONS` (docs/packml_states.md)."""
    lines: list[str] = [
        "# PackML state model",
        "",
        "Generated from `cellctl.cell.packml.TRANSITIONS` by `python -m cellctl.cell.packml_doc "
        "-o docs/packml_states.md`; do not edit by hand.",
        "",
        "Numbers are the PackTags v3.0 integers used on every interface (REST, Modbus, dashboard).",
        "",
        "## States (`Status.StateCurrent`)",
        "",
        "| # | State | Kind | In superstate |",
        "|---|---|---|---|",
    ]
    for s in PackMLState:
        kind = "acting (leaves by SC)" if s in ACTING_STATES else "wait" if s in WAIT_STATES else (
            "productive (cycle steps run here)" if s == S.EXECUTE else "not used"
        )
        sup = "Running" if s in RUNNING_STATES else "Cleared" if s in CLEARED_STATES else (
            "-" if s == S.UNDEFINED else "top level"
        )
        lines.append(f"| {s.value} | {_t(s)} | {kind} | {sup} |")
    lines += ["", "## Commands (`Command.CntrlCmd`)", "", "| # | Command | Accepted in |", "|---|---|---|"]
    for c in PackMLCommand:
        srcs = sorted(s for (s, cc) in COMMANDED if cc == c)
        lines.append(f"| {c.value} | {_t(c)} | {', '.join(_t(s) for s in srcs) or 'never'} |")
    lines += ["", "## Transitions", "", "| From | Trigger | To |", "|---|---|---|"]
    for e in TRANSITIONS:
        trig = "SC (state complete)" if isinstance(e.trigger, Trigger) else f"{_t(e.trigger)} ({e.trigger.value})"
        lines.append(f"| {_t(e.source)} ({e.source.value}) | {trig} | {_t(e.target)} ({e.target.value}) |")
    cmds = [c for c in PackMLCommand if c != C.UNDEFINED]
    lines += [
        "",
        "## State x command matrix",
        "",
        "Each cell is the next state; `-` means refused (REST 409, Modbus cmd_result = 1).",
        "",
        "| State | " + " | ".join(_t(c) for c in cmds) + " | SC |",
        "|---|" + "---|" * (len(cmds) + 1),
    ]
    for s in PackMLState:
        row = [_t(COMMANDED[(s, c)]) if (s, c) in COMMANDED else "-" for c in cmds]
        row.append(_t(STATE_COMPLETE[s]) if s in STATE_COMPLETE else "-")
        lines.append(f"| {_t(s)} | " + " | ".join(row) + " |")
    mcs = ", ".join(_t(s) for s in sorted(mode_change_states))
    lines += [
        "",
        "## Unit modes (`Status.UnitModeCurrent`)",
        "",
        "| # | Mode |",
        "|---|---|",
        *(f"| {m.value} | {_t(m)} |" for m in UnitMode),
        "",
        f"A mode change is accepted only in: {mcs} (configurable). Mode 0 cannot be requested.",
        "",
        "## Cycle steps (sub-state of Execute)",
        "",
        "| # | Step |",
        "|---|---|",
        *(f"| {st.value} | {st.name.lower()} |" for st in CycleStep),
        "",
        "A step other than none is entered only in Execute. It is kept through "
        + ", ".join(_t(s) for s in sorted(CYCLE_STATES - {S.EXECUTE}))
        + " (they return to Execute) and reset to none on entering any other state.",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    return markdown_doc_main(argv, prog="python -m cellctl.cell.packml_doc", description=__doc__.splitlines()[0], render=render_markdown)


if __name__ == "__main__":
    raise SystemExit(main())
