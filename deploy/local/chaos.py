"""`hubctl up --chaos N`: kill -9 N processes of the run (hubs or the controller) at random moments.

The plan comes from the seed alone (`plan_chaos`): the same seed gives the same victims at the same
moments. A moment is a point of the run's progress, not of the clock, so that it means the same on
a fast and a slow machine: "once K operations are finished, D seconds later". K leaves at least
two operations to do, so that a kill comes before the run's end; victims are drawn as rounds of a
shuffle of every process, so that none is killed again before every other one was (a process
killed many times would wait ever longer for its restart and could hit its start limit).

`Chaos` carries the plan out on a running station: the supervisor restarts what it kills.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from .supervisor import run_line

MAX_DELAY_S = 1.0  # after the operations count is reached: within the next operation or so


@dataclass(frozen=True)
class Kill:
    victim: str  # a process of the run: the controller or a hub
    after_operations: int  # once this many operations are finished ...
    delay_s: float  # ... this much later


@dataclass(frozen=True)
class ChaosPlan:
    seed: int
    kills: tuple[Kill, ...]  # in the order of their moments

    def describe(self) -> str:
        return ", ".join(f"{k.victim} at {k.after_operations} operations + {k.delay_s:.2f} s" for k in self.kills)


def plan_chaos(count: int, seed: int, processes: Sequence[str], operations: int) -> ChaosPlan:
    """`count` kills among `processes` (names, in a fixed order) for a run of `operations` operations."""
    if count < 0:
        raise ValueError(f"--chaos {count}: the number of kills cannot be negative")
    if not processes:
        raise ValueError("no process to kill")
    rng = random.Random(seed)
    victims: list[str] = []
    while len(victims) < count:
        round_ = list(processes)
        rng.shuffle(round_)
        victims += round_
    latest = max(0, operations - 2)
    kills = [Kill(victim, rng.randint(0, latest), round(rng.uniform(0.0, MAX_DELAY_S), 2))
             for victim in victims[:count]]
    return ChaosPlan(seed, tuple(sorted(kills, key=lambda k: (k.after_operations, k.delay_s))))


class Chaos:
    """Carries a plan out: `observe` after each status (and now and then without one) kills what is due. A
    kill whose victim is waiting for its restart waits for it to run again."""

    def __init__(self, plan: ChaosPlan, kill: Callable[[str], int | None], say: Callable[[str], object],
                 clock: Callable[[], float]) -> None:
        """`kill(name)`: SIGKILL to the process, its pid, or None while it is not running (the supervisor's)."""
        self.plan = plan
        self.kill = kill
        self.say = say
        self.clock = clock
        self.began = clock()
        self.pending = list(plan.kills)
        self.done: list[Kill] = []
        self._reached: dict[int, float] = {}  # operations finished -> when first seen

    def observe(self, finished_operations: int | None) -> None:
        """`finished_operations`: the latest status's count (None: no status yet: nothing is killed before the
        station has reported once)."""
        now = self.clock()
        if finished_operations is not None:
            for k in range(finished_operations + 1):
                self._reached.setdefault(k, now)
        for kill in list(self.pending):
            reached = self._reached.get(kill.after_operations)
            if reached is None or now < reached + kill.delay_s:
                continue
            pid = self.kill(kill.victim)
            if pid is None:
                continue
            self.pending.remove(kill)
            self.done.append(kill)
            self.say(run_line(now - self.began, f"CHAOS  kill -9 {kill.victim} (pid {pid}), "
                                                f"{len(self.done)} of {len(self.plan.kills)}"))

    def summary(self) -> str:
        left = f"; not done (the run ended first): {', '.join(k.victim for k in self.pending)}" if self.pending else ""
        return f"chaos (seed {self.plan.seed}): {len(self.done)} of {len(self.plan.kills)} kills done{left}"
