"""Ending background tasks for sure: cancel, wait, and cancel again while one still runs."""

from __future__ import annotations

import asyncio
from collections.abc import Sequence
from typing import Any

RETRY_S = 0.5  # a task still running this long after its cancel is cancelled again


async def cancel_until_done(tasks: Sequence[asyncio.Task[Any]], *, retry_s: float = RETRY_S) -> None:
    """Cancel ``tasks`` and wait until every one has ended, cancelling again each ``retry_s`` (s) one runs on.

    Python 3.11's ``asyncio.wait_for`` returns its call's result when a cancellation lands as the call
    completes; a loop around such a call then runs on as if never cancelled, and one cancel and an
    await would wait for ever. Their outcomes (errors included) are collected and dropped.
    """
    while pending := [t for t in tasks if not t.done()]:
        for t in pending:
            t.cancel()
        await asyncio.wait(pending, timeout=retry_s)
    await asyncio.gather(*tasks, return_exceptions=True)
