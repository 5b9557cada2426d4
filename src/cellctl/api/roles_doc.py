"""The REST roles as Markdown: ``docs/api_roles.md``, rendered from ``cellctl.api.auth.ROUTE_ROLES``.

A test keeps the committed file equal to it. Regenerate with ``python -m cellctl.api.roles_doc -o docs/api_roles.md``.
"""

from __future__ import annotations

from cellctl.api.auth import ROUTE_ROLES
from cellctl.config.api import ROLE_RIGHTS, ApiRole
from cellctl.markdown_doc import markdown_doc_main


def render_markdown() -> str:
    """Roles, then every mutating route with the least role it needs (docs/api_roles.md)."""
    lines = [
        "# REST API roles",
        "",
        "Generated from `cellctl.api.auth.ROUTE_ROLES` by `python -m cellctl.api.roles_doc -o docs/api_roles.md`; "
        "do not edit by hand.",
        "",
        "Each `[[api.tokens]]` entry has a `role` (the OPC UA users' names); each role may do all the roles above it "
        "may. A token without `role` is an `engineer`. A route that needs a higher role than the token's answers 403, "
        "its `detail` naming both roles.",
        "",
        "| Role | May |",
        "|---|---|",
        *(f"| `{r.value}` | {ROLE_RIGHTS[r]} |" for r in ApiRole),
        "",
        "| Route | Needs |",
        "|---|---|",
    ]
    order = list(ApiRole)
    for (method, path), role in sorted(ROUTE_ROLES.items(), key=lambda kv: (order.index(kv[1]), kv[0][1])):
        lines.append(f"| `{method} {path}` | `{role.value}` |")
    lines += [
        "",
        "Every other route reads (`GET`, and `POST /jobs/plan`, which only plans): anyone with `[api] open_reads = true`, "
        "any token (a `viewer` and up) with `false`; `/health` (its `ok`) and `/health/live` stay open.",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    return markdown_doc_main(argv, prog="python -m cellctl.api.roles_doc", description=__doc__.splitlines()[0], render=render_markdown)


if __name__ == "__main__":
    raise SystemExit(main())
