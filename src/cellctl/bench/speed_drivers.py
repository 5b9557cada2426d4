"""``cellctl bench speed``, driver figures: ``python -m keyence_lkg.bench`` and ``abb_robot.bench`` as subprocesses."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import time
from typing import Any

DRIVER_TIMEOUT_S = 600.0


def run_driver_bench(module: str, args: list[str]) -> dict[str, Any]:
    """``python -m module args`` as a subprocess; its output as printed (or why it could not run)."""
    if importlib.util.find_spec(module.split(".")[0]) is None or importlib.util.find_spec(module) is None:
        return {"command": f"python -m {module}", "skipped": f"{module} is not installed"}
    cmd = [sys.executable, "-m", module, *args]
    t0 = time.monotonic()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=DRIVER_TIMEOUT_S, check=False)
    except subprocess.TimeoutExpired:
        return {"command": " ".join(["python", "-m", module, *args]), "skipped": f"no result within {DRIVER_TIMEOUT_S:g} s"}
    return {
        "command": " ".join(["python", "-m", module, *args]),
        "exit_code": p.returncode,
        "seconds": time.monotonic() - t0,
        "output": p.stdout.rstrip(),
        "stderr_tail": p.stderr.strip().splitlines()[-5:] if p.returncode else [],
    }
