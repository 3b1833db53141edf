"""Noticing that the controller goes round in circles (DESIGN.md §4).

A plan the devices cannot follow fails the same way each time: the state leaves the plan at the
same place, the same goals are asked from the same state, and the same plan comes back. The watch
counts the requests for each goal set from each state since the last progress: an operation
finished. A plan step done is not progress by itself, even into a state not seen before: devices
that work at once interleave their effects in a different order each round (their durations are
intervals), so the rounds of one circle keep passing through new states. Counting from those
(`build_random_timed_station(0, followable=False)`, tests/stations/random_timed_station.py: two
robots, each losing its feeder's sensor) put off the diagnosis from 4 s to 31 s of station time and
the stop past a minute, and let one state be asked from more than `GIVE_UP_AFTER` times in a run.
The state the request is asked from, estimated values included, already says whether the world
moved on: the same full state again between two finished operations is a circle.

What the count means is `Repeat`: asked again, the planner searches afresh instead of handing
back the plan it remembers (`controller/planner/reuse.py`); asked again after the plan from here
lost an effect it needed, the controller puts the operations in `error` with the diagnosis and
retries them with backoff (controller/control.py), `RETRIES` times: a station whose timing no plan
can follow stops within a minute, the diagnosis said. Asked `GIVE_UP_AFTER` times from one state,
whatever the cause, the operations go to `error` too. Either way they then wait for the operator.
"""

from __future__ import annotations

import enum

from common.model.compiled import State

LOOP_AFTER = 3  # requests from one state: the third one after a lost effect is a livelock
GIVE_UP_AFTER = 20  # requests from one state: no further retry (the operator starts the operation again)
RETRIES = 4  # of a livelock, after 2, 4, 8 and 16 s (control.py's backoff): then the operator decides


class Repeat(enum.Enum):
    FIRST = "first"  # not asked from this state since the last progress
    AGAIN = "again"  # asked before: plan afresh, not the remembered plan
    LOOP = "loop"  # asked LOOP_AFTER times or more: a livelock if the plan from here lost an effect
    GIVE_UP = "give up"  # asked GIVE_UP_AFTER times: no further retry


class LivelockWatch:
    def __init__(self) -> None:
        self._asked: dict[tuple[frozenset[str], State], int] = {}

    def finished(self) -> None:
        """An operation finished: progress, and every state may be new again."""
        self._asked.clear()

    def asked(self, goals: frozenset[str], state: State) -> tuple[Repeat, int]:
        """Count a request for `goals` from `state`; what the count means, and the count."""
        key = (goals, state)
        count = self._asked[key] = self._asked.get(key, 0) + 1
        if count >= GIVE_UP_AFTER:
            return Repeat.GIVE_UP, count
        if count >= LOOP_AFTER:
            return Repeat.LOOP, count
        return (Repeat.AGAIN if count > 1 else Repeat.FIRST), count
