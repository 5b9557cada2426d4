"""The twin's time line: what a clock on the cell would read if the twin ran in real time.

The twin shortens every simulated wait (a move, a device's latency) by ``time_scale``; its time
line puts the shortened part back, so a cycle timed on it takes the robot time a real cell would,
while the computing between waits counts at its real duration. The twin's own computing (rendering
a frame, casting the laser's rays) is physics a real cell does not wait for: the clock stands still
while it runs (:meth:`TwinTimeline.unclocked`), and the device spends its modelled time instead.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager


class TwinTimeline:
    """Seconds on the simulated cell's clock: real monotonic time plus ``(1 - time_scale)`` of every simulated wait.

    Thread-safe: the protocol fakes wait in their own threads.
    """

    def __init__(self, time_scale: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.time_scale = float(time_scale)
        self._clock = clock
        self._ahead_s = 0.0
        self._lock = threading.Lock()
        self._unclocked = 0  # blocks of the twin's computing under way
        self._stood_s = 0.0  # the real time when the first of them began
        self._spent: dict[str, float] = {}  # simulated seconds waited, by what they were spent on

    def now(self) -> float:
        """The cell's clock (s)."""
        with self._lock:
            return (self._stood_s if self._unclocked else self._clock()) + self._ahead_s

    @contextmanager
    def unclocked(self) -> Iterator[None]:
        """The twin's own computing: the cell's clock stands still while it runs (waits begun meanwhile still count).

        Thread-safe and re-entrant; overlapping blocks stand the clock still once, for their union.
        """
        with self._lock:
            if not self._unclocked:
                self._stood_s = self._clock()
            self._unclocked += 1
        try:
            yield
        finally:
            with self._lock:
                self._unclocked -= 1
                if not self._unclocked:
                    self._ahead_s -= self._clock() - self._stood_s

    def waited(self, simulated_s: float, spent_on: str = "other") -> None:
        """A wait of ``simulated_s`` simulated seconds begins (negative: the rest of one was cut off),
        spent on ``spent_on`` (e.g. "moves at 1000 mm/s", "laser read-out")."""
        with self._lock:
            self._ahead_s += float(simulated_s) * (1.0 - self.time_scale)
            self._spent[spent_on] = self._spent.get(spent_on, 0.0) + float(simulated_s)

    def spent(self) -> dict[str, float]:
        """The simulated seconds waited so far, by what they were spent on (a copy)."""
        with self._lock:
            return dict(self._spent)
