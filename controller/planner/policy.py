"""Planning policy: how much a request may spend, what answers it streams, and when a goal without a plan
is tried again. The controller core, the planner worker, the in-process runner and replay share it.

Live, the limits are wall-clock seconds and a newer request stops the improvement of an older one; in
virtual time they are counts of expanded states, so that a seed reproduces a run on any machine.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Generator, Mapping
from typing import Protocol

from common.model import Predicate
from common.model.compiled import State
from common.wire.ctl import PlannedAlone

from .planner import Planner
from .plans import NoPlan, Plan
from .portfolio import Budget
from .reuse import memory_key

log = logging.getLogger("statehub.controller.planner")

FIRST_ANSWER_S = 3.0  # the satisficing member's wall-clock limit (it answers well inside it)
IMPROVE_S = 10.0  # then A* and the symbolic member, unless a newer request comes
HOLD_S = 0.15  # a warm A* may replace the first answer by a shortest plan this soon
FIRST_RETIME_S = 0.02  # the first plan is improved by time this long at most before it goes out
RETIME_S = 2.0  # then the best plan is improved by time (controller/retime.py) for at most this long
RETIME_LIVE_TRIES = 2_000  # and at most this many orders of its steps checked (a plan of 240 steps: ~1 s)

RETRY_FIRST_S = 2.0  # a goal without a plan is tried again after this, then twice as long each time
RETRY_MAX_S = 60.0


def live_budget(first_seconds: float = FIRST_ANSWER_S, improve_seconds: float = IMPROVE_S,
                hold_seconds: float = HOLD_S, stop: Callable[[], bool] | None = None,
                leftovers: list[object] | None = None) -> Budget:
    """Wall-clock limits for a live controller: the satisficing member answers well inside `first_seconds`;
    `stop` (a newer request waits) ends the work under way at its next safe point, leaving the stopped
    search's tables in `leftovers` to be freed later."""
    return Budget(first_expansions=1_000_000, improve_expansions=1_000_000, symbolic_layers=100_000,
                  seconds=first_seconds, improve_seconds=improve_seconds, hold_seconds=hold_seconds, stop=stop,
                  leftovers=leftovers)


# Counts only: in virtual time a seed reproduces a run on any machine. No improvement by default: A*'s
# tables for each new goal set cost about a second to build, which is most of an in-process run's time.
VIRTUAL_BUDGET = Budget(first_expansions=20_000, improve_expansions=0, symbolic_layers=500)


class PlanQuestion(Protocol):
    """What is planned for: the controller's `PlanRequest` is one."""

    @property
    def start(self) -> State: ...
    @property
    def goals(self) -> Mapping[str, Predicate]: ...
    @property
    def disabled(self) -> frozenset[str]: ...
    @property
    def reuse(self) -> bool: ...  # False: the same goals came back from a state without progress (livelock.py)
    @property
    def keep(self) -> Mapping[str, Predicate]: ...  # finished operations' goals to leave holding (kept_product.py)


Answered = tuple[Plan | NoPlan | None, PlannedAlone | None]


def anytime_answers(planner: Planner, question: PlanQuestion, budget: Budget) -> Generator[Answered, None, None]:
    """The answers to one request: the portfolio's for all goals together, the kept ones included; if none
    reaches them with the kept goals, the same without those; if it neither finds a plan nor shows one
    impossible, the first goal alone that has one (progress over minimality, as the original planner did
    for hard cases), with a note that says so. Plans name the request's goals only."""
    if not question.goals:
        yield None, None
        return
    kept = {name: goal for name, goal in question.keep.items() if name not in question.goals}
    attempts = [{**question.goals, **kept}, dict(question.goals)] if kept else [dict(question.goals)]
    last: Plan | NoPlan | None = None
    for goals in attempts:
        if not question.reuse:  # the controller saw this request go round in circles: no remembered plan
            planner.memory.forget(memory_key(goals, question.disabled))
        for last in planner.plan_anytime(question.start, goals, question.disabled, budget):
            if isinstance(last, Plan):
                yield _naming_only(last, question.goals), None
        if isinstance(last, Plan):
            return
        if len(goals) > len(question.goals):
            log.warning("no plan reaches %s and keeps %s as finished (%s): planning without keeping them",
                        ", ".join(question.goals), ", ".join(kept), last)
    assert isinstance(last, NoPlan)
    if not last.proven and len(question.goals) > 1:
        for name, goal in question.goals.items():
            single = planner.plan(question.start, {name: goal}, question.disabled, budget=budget)
            if isinstance(single, Plan):
                yield single, PlannedAlone(name, len(question.goals), last.reason)
                return
    yield last, None


def _naming_only(plan: Plan, goals: Mapping[str, Predicate]) -> Plan:
    """The plan as the answer to the request: it names the request's goals, not the kept ones."""
    if len(plan.goals) == len(goals):
        return plan
    return dataclasses.replace(plan, goals=tuple(name for name in plan.goals if name in goals))


def solve_goals(planner: Planner, question: PlanQuestion, budget: Budget) -> Answered:
    """The last (best) of `anytime_answers`: what a caller that can wait for the whole budget takes."""
    best: Answered = (None, None)
    for answer, note in anytime_answers(planner, question, budget):
        best = (answer, note if note is not None else best[1])
    return best
