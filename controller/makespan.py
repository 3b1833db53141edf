"""How long a plan takes if every step starts as early as its causal order allows (`hubctl plan`).

A step waits for every earlier step it depends on through the model's own guards and actions:
one that writes what it reads (its condition comes from there), one that reads what it writes (it
must not take that step's condition away while the step is due: an effect reads its guard until it
happens) and one that writes what it writes (their order decides the value). The supervisor's
synthesized guards do not order steps here. Each effect takes the longest its duration allows;
deliberate and automatic steps take no time. A prediction, not a schedule the engine follows.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from common.model import DurationTable, Transition


@dataclass(frozen=True)
class TimedStep:
    transition: str
    start_s: float
    finish_s: float


def earliest_schedule(steps: Sequence[Transition], durations: DurationTable) -> tuple[TimedStep, ...]:
    """Each step's earliest start and finish, in the plan's order."""
    timed: list[TimedStep] = []
    for number, step in enumerate(steps):
        reads, writes = step.read(), step.written()
        start = 0.0
        for earlier, done in zip(steps[:number], timed, strict=True):
            earlier_writes = earlier.written()
            if earlier_writes & reads or earlier_writes & writes or earlier.read() & writes:
                start = max(start, done.finish_s)
        timed.append(TimedStep(step.name, start, start + durations.of_transition(step).max_s))
    return tuple(timed)


def makespan(schedule: Sequence[TimedStep]) -> float:
    return max((s.finish_s for s in schedule), default=0.0)
