"""``cellctl``'s parser loads no more than its commands' options: the service, the calibration code, scipy and OpenCV
are imported by the command that runs them. ``cellctl status`` or ``parts export`` on a line PC (and each call a
PLC-side script makes) started in 0.9 s when the parser pulled in the whole service; 0.45 s without it.
"""

from __future__ import annotations

import json
import subprocess
import sys

HEAVY = (
    "scipy", "cv2", "fastapi", "uvicorn", "asyncua", "pymodbus", "cellctl.service.compose", "cellctl.calibration",
    "cellctl.align", "cellctl.commissioning.cli", "cellctl.commissioning.registry", "cellctl.sim", "cellctl.bench.accuracy",
)  # fmt: skip

PROBE = f"""
import json, sys
from cellctl.cli import build_parser
build_parser().parse_args(["status"])
print(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))
"""


def test_building_the_parser_imports_none_of_the_commands_heavy_modules() -> None:
    run = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    loaded = json.loads(run.stdout.strip().splitlines()[-1])
    assert loaded == [], f"building cellctl's parser imported {loaded}: import them in the command that needs them"
