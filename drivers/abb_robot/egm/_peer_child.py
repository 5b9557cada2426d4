"""``python -m abb_robot.egm._peer_child <settings-json> <shm-name>``: the EGM peer's child process.

Kept apart from :mod:`abb_robot.egm.peer_process` so that running it does not import the module
it executes twice.
"""

import json
import sys
from types import SimpleNamespace

from abb_robot.egm.peer_process import child_main

if __name__ == "__main__":
    child_main(SimpleNamespace(**json.loads(sys.argv[1])), sys.argv[2])
