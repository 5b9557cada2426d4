"""Give the heap's free memory back to the system after heavy work in worker threads.

Rendering, board detection and fits run in worker threads; glibc gives each thread its own
malloc arena and keeps what they freed, so a commissioning run leaves the process holding
hundreds of MB it no longer uses (measured: 998 MB resident after commissioning, 326 MB after
``malloc_trim``). Other C libraries have no such call; there this does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import logging

log = logging.getLogger(__name__)


@functools.cache
def _malloc_trim() -> object | None:
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        fn = ctypes.CDLL(name).malloc_trim
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_size_t]
    fn.restype = ctypes.c_int
    return fn


def release_free_memory() -> bool:
    """Return freed heap memory to the system (glibc ``malloc_trim``); True if the call exists here."""
    fn = _malloc_trim()
    if fn is None:
        return False
    fn(0)  # type: ignore[operator]
    return True
