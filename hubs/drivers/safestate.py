"""Recognising the write that follows ``safe_state()``.

``Driver.safe_state()`` returns the command values to apply when the controller is
silent; a variable it leaves out keeps its value.  A hub runtime may still write the
left-out variables right after calling it (re-writing the last applied command, or the
initial values when nothing was applied yet).  For drivers whose ``write`` starts
motion (lift, robot) or whose output must never change by itself (tool changer lock),
that write must not undo the safe state.  ``SafeStateWrite`` marks the moment
``safe_state()`` was called; the first ``write`` within ``window`` seconds afterwards is
that runtime write, and the driver treats it as "keep": it records the values but
neither resumes motion nor drives the outputs.  The next command resumes.
"""

from __future__ import annotations

import time


class SafeStateWrite:
    def __init__(self, window: float = 1.0) -> None:
        self.window = window
        self._since: float | None = None

    def entered(self) -> None:
        """``safe_state()`` was called."""
        self._since = time.monotonic()

    def consume(self) -> bool:
        """True for the first write within ``window`` s after ``safe_state()``; resets the mark."""
        since, self._since = self._since, None
        return since is not None and time.monotonic() - since <= self.window
