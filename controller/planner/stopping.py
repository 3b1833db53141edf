"""Cooperative stopping: a newer request ends the work under way at a safe point.

A search looks at its stop test every so many expansions and returns (`SearchEnd.STOPPED`). A table
builder (A*'s projections and distance tables, the symbolic member's encoding) is deep in loops that
return nothing useful half way, so it calls `check_stop`, which raises `Stopped`. A builder calls it only
while what it builds is still its own (locals, an object not yet stored in a cache): what it shares, it
stores whole after its last check. So a stopped build leaves nothing half built behind, and the next
request finds every cache as complete as before.
"""

from __future__ import annotations

from collections.abc import Callable

StopTest = Callable[[], bool]  # True: end the work under way (a newer request waits)


class Stopped(Exception):
    """A table build ended early by its stop test. Nothing it had built is kept."""


def check_stop(stop: StopTest | None) -> None:
    """Raise `Stopped` when `stop` says so. A system call per call: called per unit of real work
    (a transition, a layer), not per state."""
    if stop is not None and stop():
        raise Stopped
