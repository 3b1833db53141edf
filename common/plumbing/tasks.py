"""Ending a process's tasks within a bound.

`task.cancel()` then `await task` can wait forever: a task may swallow its cancellation
(Python 3.11's `asyncio.wait_for` does when the awaited future completes in the same loop
iteration as the cancel) and go on looping. A process that waits for it never reaches its
safe state or its exit. Here a task that is still running is cancelled again until it ends
or the bound passes; what is left is named, not waited for.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Iterable

RECANCEL_EVERY_S = 0.05


async def cancel_and_wait(tasks: Iterable[asyncio.Task[object]], timeout: float,
                          log: logging.Logger | None = None) -> list[str]:
    """Cancel `tasks` and wait up to `timeout` seconds for them to end, cancelling again those that go
    on; returns the names of those still running (logged as a warning when `log` is given)."""
    tasks = list(tasks)
    pending = {task for task in tasks if not task.done()}
    for task in pending:
        task.cancel()
    deadline = time.monotonic() + timeout
    while pending:
        left = deadline - time.monotonic()
        if left <= 0:
            break
        _, pending = await asyncio.wait(pending, timeout=min(RECANCEL_EVERY_S, left))
        for task in pending:
            task.cancel()
    for task in tasks:
        if task.done() and not task.cancelled():
            task.exception()  # retrieved: its failure was reported where it happened
    stuck = sorted(task.get_name() for task in pending)
    if stuck and log is not None:
        log.warning("tasks still running %.1f s after they were cancelled, left behind: %s", timeout,
                    ", ".join(stuck))
    return stuck
