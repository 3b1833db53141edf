"""Ending the planner worker's improvement of an old request when a new one arrives.

The improvement (A* building pattern databases for a new goal set, then searching) runs in
loops that look at no clock and can take a second; a request that arrives meanwhile would
wait for it. The controller follows every request with `PREEMPT_SIGNAL`; the worker's handler
raises `Preempted` in the worker's main thread only inside an `allowed()` section and only when
a request is really waiting, so a stray or late signal changes nothing.

`Preempted` derives from BaseException so that no `except Exception` on the way swallows it.
Whatever the interrupted code was building may be half done: the caller drops those tables
(`Planner.forget_partial_work`).
"""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Iterator
from multiprocessing.connection import Connection
from types import FrameType

PREEMPT_SIGNAL = signal.SIGUSR1


class Preempted(BaseException):
    """A newer plan request is waiting: the improvement under way ends here."""


class Preemption:
    def __init__(self, requests: Connection) -> None:
        self._requests = requests
        self._allowed = False
        signal.signal(PREEMPT_SIGNAL, self._on_signal)

    def _on_signal(self, _signum: int, _frame: FrameType | None) -> None:
        if self._allowed and self._requests.poll():
            self._allowed = False
            raise Preempted

    @contextlib.contextmanager
    def allowed(self, allowed: bool = True) -> Iterator[None]:
        """Inside: a signal with a request waiting raises Preempted (when `allowed`)."""
        self._allowed = allowed
        try:
            yield
        finally:
            self._allowed = False
