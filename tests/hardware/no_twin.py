"""Run ``cellctl`` in a Python that cannot import the twin (``cellctl.sim`` and its submodules).

    python tests/hardware/no_twin.py --config cell.toml serve ...

A finder first on ``sys.meta_path`` refuses every import of ``cellctl.sim`` with ImportError and
writes ``no_twin: refused import of <name>`` to stderr, so a test also sees an attempt that some
code swallowed. Used by tests/hardware for the service and the CLI in hardware mode.
"""

from __future__ import annotations

import importlib.abc
import sys
from collections.abc import Sequence
from importlib.machinery import ModuleSpec
from types import ModuleType

TWIN = "cellctl.sim"
REFUSED_MARK = "no_twin: refused import of"


class _NoTwin(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname: str, path: Sequence[str] | None = None, target: ModuleType | None = None) -> ModuleSpec | None:
        if fullname == TWIN or fullname.startswith(TWIN + "."):
            print(f"{REFUSED_MARK} {fullname}", file=sys.stderr, flush=True)
            raise ImportError(f"{fullname}: the twin cannot be imported in this process (hardware mode test)", name=fullname)
        return None


def block_twin() -> None:
    """Make ``cellctl.sim`` unimportable in this interpreter (it must not be imported yet)."""
    loaded = [m for m in sys.modules if m == TWIN or m.startswith(TWIN + ".")]
    if loaded:
        raise RuntimeError(f"the twin is already imported: {', '.join(sorted(loaded))}")
    if not any(isinstance(f, _NoTwin) for f in sys.meta_path):
        sys.meta_path.insert(0, _NoTwin())


if __name__ == "__main__":
    block_twin()
    from cellctl.cli import main

    raise SystemExit(main(sys.argv[1:]))
