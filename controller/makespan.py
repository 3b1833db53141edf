"""How long a plan takes if every step starts as early as its causal order allows (`hubctl plan`).

A step waits for every earlier step it depends on through the model's own guards and actions:
one that writes what it reads (its condition comes from there), one that reads what it writes (it
must not take that step's condition away while the step is due: an effect reads its guard until it
happens) and one that writes what it writes (their order decides the value). The supervisor's
synthesized guards do not order steps here. Each effect takes the longest its duration allows;
deliberate and automatic steps take no time.

An effect does not wait once its guard holds: it starts when the steps that last wrote what it reads
have finished. When it has to start later (a step before it in the plan must finish first), the
commands among those steps are put off to then, and what follows them moves with them. A plan that
counts on a race (the effect is also enabled by an effect or an automatic step, which cannot be put
off, or putting the command off never settles) is scheduled as if its effects waited. A prediction,
not a schedule the engine follows.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from common.model import DurationTable, Transition, TransitionKind


@dataclass(frozen=True)
class TimedStep:
    transition: str
    start_s: float
    finish_s: float


def earliest_schedule(steps: Sequence[Transition], durations: DurationTable) -> tuple[TimedStep, ...]:
    """Each step's earliest start and finish, in the plan's order."""
    taking = [durations.of_transition(step).max_s for step in steps]
    waits_for: list[list[int]] = []  # the earlier steps each step depends on
    enabled_by: list[set[int]] = []  # the steps that last wrote what it reads: its condition's origin
    last_writer: dict[str, int] = {}
    for number, step in enumerate(steps):
        reads, writes = step.read(), step.written()
        waits_for.append([i for i, earlier in enumerate(steps[:number])
                          if earlier.written() & (reads | writes) or earlier.read() & writes])
        enabled_by.append({last_writer[p] for p in reads if p in last_writer})
        last_writer.update(dict.fromkeys(writes, number))
    first = _schedule(taking, waits_for, [0.0] * len(steps))
    not_before = [0.0] * len(steps)  # commands put off until the effects they enable can start
    start = first
    for _round in range(len(steps) + 1):
        put_off = False
        for number, step in enumerate(steps):
            if step.kind is not TransitionKind.EFFECT:
                continue
            commands = [i for i in enabled_by[number] if steps[i].kind is TransitionKind.DELIBERATE]
            # What the effect reads from other steps (effects, automatic ones) is there when it is: no later.
            floor = max((start[i] + taking[i] for i in enabled_by[number] if i not in commands), default=0.0)
            if start[number] <= floor + 1e-9:
                continue
            for i in commands:
                if start[i] < start[number] - 1e-9:
                    not_before[i] = start[number]
                    put_off = True
        if not put_off:
            return _timed(steps, start, taking)
        start = _schedule(taking, waits_for, not_before)
    return _timed(steps, first, taking)  # the plan counts on a race: scheduled as if its effects waited


def _schedule(taking: Sequence[float], waits_for: Sequence[Sequence[int]], not_before: Sequence[float]) -> list[float]:
    start: list[float] = []
    for number, earlier in enumerate(waits_for):
        ready = max((start[i] + taking[i] for i in earlier), default=0.0)
        start.append(max(ready, not_before[number]))
    return start


def _timed(steps: Sequence[Transition], start: Sequence[float], taking: Sequence[float]) -> tuple[TimedStep, ...]:
    return tuple(TimedStep(step.name, s, s + d) for step, s, d in zip(steps, start, taking, strict=True))


def makespan(schedule: Sequence[TimedStep]) -> float:
    return max((s.finish_s for s in schedule), default=0.0)
