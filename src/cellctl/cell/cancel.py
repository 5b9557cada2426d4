"""Ending background tasks for sure (cancel, wait, cancel again), and work that must end once begun."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Sequence
from typing import Any, TypeVar

_T = TypeVar("_T")

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


async def to_the_end(work: Awaitable[_T]) -> tuple[_T, bool]:
    """Await ``work`` to its end whatever cancels arrive meanwhile (a write begun is finished, and said so):
    its result, and whether a cancel came. The caller re-raises the cancel where it must end too."""
    fut = asyncio.ensure_future(work)
    cancelled = False
    while not fut.done():
        try:
            await asyncio.shield(fut)
        except asyncio.CancelledError:
            cancelled = True
    return fut.result(), cancelled


def cancel_first(exc: BaseException) -> None:
    """Raise CancelledError (from ``exc``) when the running task is being cancelled: an awaited call that ended the
    cancel with an error of its own (a driver's timeout as the stop came) must end the task, not count as its failure."""
    task = asyncio.current_task()
    if task is not None and task.cancelling():
        raise asyncio.CancelledError() from exc
