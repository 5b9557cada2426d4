"""The layering rules hold: import-linter checks the contracts of pyproject.toml ([tool.importlinter])."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _lint_imports() -> str:
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent)) or "lint-imports"
    return exe


def test_every_import_contract_is_kept() -> None:
    run = subprocess.run([_lint_imports()], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "6 kept, 0 broken" in run.stdout


def test_the_contracts_name_the_twin_and_the_drivers() -> None:
    import tomllib

    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    twin = next(c for c in contracts if c["forbidden_modules"] == ["cellctl.sim"])
    # The hardware root and everything it builds on are held to it; the simulated root is not.
    for module in ("cellctl.service.hardware", "cellctl.service.compose", "cellctl.commissioning", "cellctl.api"):
        assert module in twin["source_modules"]
    assert "cellctl.service.simulated" not in twin["source_modules"]


def test_the_store_never_imports_the_cell() -> None:
    import tomllib

    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    store = next(c for c in contracts if c["source_modules"] == ["cellctl.store"])
    # The cell (and the API and the service above it) use the store, never the other way round;
    # the values both need live in cellctl.domain.
    assert store["type"] == "forbidden"
    assert {"cellctl.cell", "cellctl.api", "cellctl.service"} <= set(store["forbidden_modules"])
    assert not store.get("allow_indirect_imports", False)  # not through cellctl.domain or anything else either
