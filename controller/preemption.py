"""A newer plan request ends the planner worker's improvement of an older one, at a safe point.

The worker gives each request's budget a `NewerRequest` as its stop test: it looks at the request pipe
(a poll; nothing is read). The searches ask it every so many expansions and return; the table builders
(A*'s projections and distance tables, the symbolic member's encoding) ask it per unit of work and
raise `Stopped`, but only while what they build is still their own, so nothing half built is kept
(`controller/planner/stopping.py`). No signal is involved and the planner's caches stay warm.

The first answer is never stopped, so every request gets one: the test says "stop" only once armed,
after that answer is sent. The controller sends a newer request only after the first answer anyway.
"""

from __future__ import annotations

from multiprocessing.connection import Connection


class NewerRequest:
    """The stop test of one request's work: armed, true as soon as a newer request waits."""

    def __init__(self, requests: Connection) -> None:
        self._requests = requests
        self._armed = False
        self.stopped = False  # it said "stop" at least once: the work under way ended early

    def arm(self) -> None:
        """The first answer is out: from now on a newer request ends the improvement."""
        self._armed = True

    def __call__(self) -> bool:
        if self._armed and self._requests.poll():
            self.stopped = True
            return True
        return False
