"""Shared test setup: the PLC emulator (tests/plc), the service harness (tests/service), the OPC UA client (tests/opcua) and
tests/shared_support.py are importable from every test folder."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
for folder in ("plc", "service", "opcua"):
    sys.path.insert(0, str(Path(__file__).parent / folder))


@pytest.fixture(autouse=True)
def _root_logging_restored() -> object:
    """A test that runs `cellctl ...` in-process configures the root logger (level, handler): undo it after,
    so a DEBUG level set by one test does not slow every later test (pymodbus and asyncua log each frame)."""
    root = logging.getLogger()
    level, handlers = root.level, list(root.handlers)
    yield
    for h in [h for h in root.handlers if h not in handlers]:
        root.removeHandler(h)
        h.close()
    root.setLevel(level)


def _dump_asyncio_tasks(nodeid: str) -> None:
    """Print every task of every running event loop with its stack (a hung test then says what it awaits;
    pytest-timeout's own dump shows threads only, and an idle loop's thread only shows select())."""
    import asyncio
    import gc

    out = sys.stderr
    print(f"\n+++ {nodeid}: asyncio tasks before pytest-timeout fires +++", file=out)
    loops = [o for o in gc.get_objects() if isinstance(o, asyncio.AbstractEventLoop) and o.is_running()]
    for loop in loops:
        try:
            tasks = list(asyncio.all_tasks(loop))
        except RuntimeError:  # the set changed meanwhile: one more try
            tasks = list(asyncio.all_tasks(loop))
        for task in tasks:
            print(f"--- {task!r}", file=out)
            task.print_stack(limit=25, file=out)
    out.flush()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item: pytest.Item) -> object:
    import threading

    marker = item.get_closest_marker("timeout")
    limit = float(marker.args[0]) if marker is not None and marker.args else float(item.config.getini("timeout") or 0)
    timer = None
    if limit > 30:
        timer = threading.Timer(limit - 15, _dump_asyncio_tasks, args=(item.nodeid,))
        timer.daemon = True
        timer.start()
    try:
        yield
    finally:
        if timer is not None:
            timer.cancel()
