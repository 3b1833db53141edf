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
can follow stops within a minute, the diagnosis said. Asked `GIVE_UP_AFTER` times from one state
after a plan failed, whatever the failure, the operations go to `error` too. Either way they then
wait for the operator.

Only a request because a plan failed (`PLAN_FAILED`: the state left it, a step blocked, a hold
expired, the goals not reached at its end, or the station back where it was) is a round of a circle.
A request from outside the plan is not: a hub whose link flaps while the operator works on one task
asks again from one state at each change of health (a loaded 2-core machine did it 20 times during
one confirmation, and the operations went to `error` with the station doing nothing wrong); so do
the console's goals and the retries of operations in error.
"""

from __future__ import annotations

import enum

from common.model.compiled import State
from common.wire.ctl import ReplanReason

LOOP_AFTER = 3  # requests from one state: the third one after a lost effect is a livelock
GIVE_UP_AFTER = 20  # requests from one state: no further retry (the operator starts the operation again)
RETRIES = 4  # of a livelock, after 2, 4, 8 and 16 s (control.py's backoff): then the operator decides
# The requests that count: a plan failed, or the station came back to where it was (a restored state, a
# forbidden state left again).
PLAN_FAILED = frozenset({ReplanReason.LEFT_PLAN, ReplanReason.STEP_BLOCKED, ReplanReason.RACE_HOLD_EXPIRED,
                         ReplanReason.GOALS_NOT_REACHED, ReplanReason.RESTORED, ReplanReason.SAFE_AGAIN})


class Repeat(enum.Enum):
    FIRST = "first"  # not asked from this state since the last progress
    AGAIN = "again"  # asked before: plan afresh, not the remembered plan
    LOOP = "loop"  # asked LOOP_AFTER rounds or more: a livelock if the plan from here lost an effect
    GIVE_UP = "give up"  # asked GIVE_UP_AFTER rounds: no further retry


class LivelockWatch:
    def __init__(self) -> None:
        # Per goal set and state: the requests (asked again: plan afresh) and the rounds (the first request and
        # each one because a plan failed: LOOP_AFTER and GIVE_UP_AFTER count these).
        self._asked: dict[tuple[frozenset[str], State], tuple[int, int]] = {}

    def finished(self) -> None:
        """An operation finished: progress, and every state may be new again."""
        self._asked.clear()

    def asked(self, goals: frozenset[str], state: State, *, plan_failed: bool = True) -> tuple[Repeat, int]:
        """Count a request for `goals` from `state` (`plan_failed`: asked because a plan failed, `PLAN_FAILED`);
        what the count means, and the rounds."""
        key = (goals, state)
        requests, rounds = self._asked.get(key, (0, 0))
        requests += 1
        if requests == 1 or plan_failed:
            rounds += 1
        self._asked[key] = (requests, rounds)
        if rounds >= GIVE_UP_AFTER:
            return Repeat.GIVE_UP, rounds
        if rounds >= LOOP_AFTER and plan_failed:
            return Repeat.LOOP, rounds
        return (Repeat.AGAIN if requests > 1 else Repeat.FIRST), rounds
