"""The alarm tables as Markdown: ``docs/alarm_reactions.md``, rendered from :mod:`cellctl.cell.alarm_table`.

A test keeps the committed file equal to what this renders.

Regenerate the docs with ``python -m cellctl.cell.alarms_doc -o docs/alarm_reactions.md``.
"""

from __future__ import annotations

from cellctl.cell.alarm_table import (
    ALARM_CATALOGUE,
    REACTIONS,
    RECOVERY_COMMANDS,
    STOP_REASON_RESET_COMMANDS,
)
from cellctl.domain import PackMLCommand
from cellctl.markdown_doc import markdown_doc_main


def _cmd(c: PackMLCommand | None) -> str:
    return "-" if c is None else c.name.title()


def render_markdown() -> str:
    """The reaction table and the alarm catalogue as Markdown (docs/alarm_reactions.md)."""
    lines = [
        "# Alarm reactions",
        "",
        "Generated from `cellctl.cell.alarm_table.REACTIONS` and `ALARM_CATALOGUE` by "
        "`python -m cellctl.cell.alarms_doc -o docs/alarm_reactions.md`; do not edit by hand.",
        "",
        "## Fault class -> PackML command",
        "",
        "| Category | Fault class | Robot still | Robot moving | Severity | Why |",
        "|---|---|---|---|---|---|",
    ]
    for fc, r in REACTIONS.items():
        lines.append(
            f"| {fc.value} | {fc.name.lower()} | {_cmd(r.when_still)} | {_cmd(r.when_moving)} | "
            f"{r.severity.name.lower()} | {r.why} |"
        )
    lines += [
        "",
        "A reaction the current state does not accept (e.g. Hold in Idle) is not issued; the alarm then",
        "blocks " + ", ".join(sorted(c.name.title() for c in RECOVERY_COMMANDS)) + " while it is active,",
        "and entering Execute applies the strongest pending reaction. The first alarm whose reaction",
        "stopped production is the first-out stop reason until "
        + ", ".join(sorted(c.name.title() for c in STOP_REASON_RESET_COMMANDS))
        + " is accepted.",
        "",
        "An alarm nobody acknowledged stays listed across a restart of the service, inactive, until it is",
        "acknowledged; a condition still present is raised again by the new run.",
        "",
        "## Alarm catalogue",
        "",
        "| ID | Name | Fault class | Kind | Text |",
        "|---|---|---|---|---|",
    ]
    for code, spec in ALARM_CATALOGUE.items():
        kind = "condition (until cleared)" if spec.condition else "event (until acknowledged)"
        lines.append(f"| {code.value} | {code.name.lower()} | {spec.fault_class.name.lower()} | {kind} | {spec.text} |")
    lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    return markdown_doc_main(argv, prog="python -m cellctl.cell.alarms_doc", description=__doc__.splitlines()[0], render=render_markdown)


if __name__ == "__main__":
    raise SystemExit(main())
