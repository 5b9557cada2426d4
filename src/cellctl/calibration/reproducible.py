"""OpenCV's solvers on one thread: a calibration recomputed from the same dataset gives the same bits.

``cv2.calibrateCameraExtended`` on OpenCV's thread pool (pthreads, ``cv2.getNumThreads()`` threads) sums
in an order that depends on which thread finishes first: on this project's twin views 100 runs at 2 threads
gave 23-47 different (K, dist), up to 3.5e-6 px apart, at 1 thread one (BLAS threads changed nothing). A
recompute of a part in use must give its very values (``cellctl calibrate ... --dataset``: a new id would
make every part computed with it stale), so the solvers run inside :func:`opencv_one_thread`. Their cost
is milliseconds; the board search, the slow part, keeps the pool.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

import cv2

# cv2.setNumThreads is process-wide: one section at a time, so none restores the pool while another runs.
_LOCK = threading.RLock()


@contextmanager
def opencv_one_thread() -> Iterator[None]:
    """OpenCV on one thread inside the block (process-wide; the former count restored after it)."""
    with _LOCK:
        before = cv2.getNumThreads()
        cv2.setNumThreads(1)
        try:
            yield
        finally:
            cv2.setNumThreads(before)
