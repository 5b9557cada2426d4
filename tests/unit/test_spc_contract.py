"""cellctl.quality is pure: it imports none of the cell, API, service, store, twin, benchmarks or
drivers (even indirectly), and nothing that does I/O or reads a clock."""

from __future__ import annotations

import ast
from pathlib import Path

import grimp

ROOT = Path(__file__).resolve().parents[2]
FORBIDDEN = ("cellctl.cell", "cellctl.api", "cellctl.service", "cellctl.store", "cellctl.sim", "cellctl.bench",
             "cellctl.plc", "cellctl.commissioning", "keyence_lkg", "abb_robot", "genicam_camera")  # fmt: skip
ALLOWED_IMPORTS = ("__future__", "collections", "dataclasses", "datetime", "enum", "math", "typing", "numpy",
                   "cellctl.config", "cellctl.domain", "cellctl.geometry", "cellctl.quality")  # fmt: skip


def test_quality_never_imports_the_cell_the_store_or_a_device() -> None:
    graph = grimp.build_graph("cellctl", "keyence_lkg", "abb_robot", "genicam_camera")
    upstream = graph.find_upstream_modules("cellctl.quality", as_package=True)
    bad = sorted(m for m in upstream if m.startswith(FORBIDDEN))
    assert not bad, f"cellctl.quality imports {bad}"


def test_quality_imports_only_pure_modules() -> None:
    files = sorted((ROOT / "src/cellctl/quality").glob("*.py"))
    assert len(files) >= 2
    for f in files:
        tree = ast.parse(f.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            for name in names:
                assert name.split(".")[0] in {"__future__", *(x.split(".")[0] for x in ALLOWED_IMPORTS)}, (f, name)
                if name.startswith("cellctl"):
                    assert name.startswith(ALLOWED_IMPORTS), (f.name, name)
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
                assert node.func.attr not in ("now", "utcnow", "today", "time"), (f.name, "reads a clock")
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
                assert node.func.id not in ("open", "print", "input"), (f.name, node.func.id)
