"""The twin's time line: what a clock on the cell would read if the twin ran in real time.

The twin shortens every simulated wait (a move, a device's latency) by ``time_scale``; its time
line puts the shortened part back, so a cycle timed on it takes the robot time a real cell would,
while the computing between waits counts at its real duration.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


class TwinTimeline:
    """Seconds on the simulated cell's clock: real monotonic time plus ``(1 - time_scale)`` of every simulated wait.

    Thread-safe: the protocol fakes wait in their own threads.
    """

    def __init__(self, time_scale: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.time_scale = float(time_scale)
        self._clock = clock
        self._ahead_s = 0.0
        self._lock = threading.Lock()

    def now(self) -> float:
        """The cell's clock (s)."""
        with self._lock:
            return self._clock() + self._ahead_s

    def waited(self, simulated_s: float) -> None:
        """A wait of ``simulated_s`` simulated seconds begins (negative: the rest of one was cut off)."""
        with self._lock:
            self._ahead_s += float(simulated_s) * (1.0 - self.time_scale)
