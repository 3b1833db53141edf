"""The planner's memory of its last plan per goal set, so a request asked again costs no search.

The controller asks the same goals again when a newer request stopped the last one, when a
plan step failed and the state went back onto the plan, or when an operator retries; a
benchmark asks them twice. If the new start is a state the remembered plan passes through,
the rest of that plan from there is a plan from the start: it is handed back as moves, to be
validated by simulation like every other member's plan. The rest of a shortest plan is a
shortest plan from where it starts (a shorter one would shorten the whole), so the rest of a
plan shown minimal is minimal too.

`SearchMemory` keeps what the satisficing member settled per question (start, goal, the request's
goals, disabled resources, expansion count): a station running orders comes back to the states it planned
from before (the product reset, the devices home) and asks the same questions each order. The member is
deterministic given the question, so its remembered answer is the one it would find again; an answer cut
short by the wall clock is not kept (with more time it may differ).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass

from common.model import Predicate
from common.model.compiled import CompiledModel, State

from .plans import Plan, moves_of
from .steps import Move

PLANS_KEPT = 64  # goal sets remembered (a run asks a few dozen)
SEARCHES_KEPT = 256  # questions remembered (two variants' orders ask a few dozen distinct ones)

Key = tuple[tuple[Predicate, ...], frozenset[str]]  # the goals, the disabled resources


def memory_key(goals: Mapping[str, Predicate], disabled: frozenset[str]) -> Key:
    return tuple(goals.values()), frozenset(disabled)


class PlanMemory:
    def __init__(self, compiled: CompiledModel, kept: int = PLANS_KEPT) -> None:
        self.compiled = compiled
        self.kept = kept
        self._plans: OrderedDict[Key, Plan] = OrderedDict()

    def __len__(self) -> int:
        return len(self._plans)

    def remember(self, key: Key, plan: Plan) -> None:
        self._plans[key] = plan
        self._plans.move_to_end(key)
        if len(self._plans) > self.kept:
            self._plans.popitem(last=False)

    def recall(self, key: Key, start: State) -> tuple[list[Move], bool] | None:
        """The rest of the plan remembered for these goals from `start`, and whether it is a shortest one;
        None when no plan is remembered or `start` is on none."""
        plan = self._plans.get(key)
        if plan is None:
            return None
        try:
            position = plan.states.index(start)
        except ValueError:
            return None
        return moves_of(self.compiled, plan.steps[position:]), plan.stats.minimal

    def forget(self, key: Key) -> None:
        """Hand back no plan for these goals until one is found again: the controller asked them again from a
        state it had already planned from, with no progress since (controller/livelock.py)."""
        self._plans.pop(key, None)

    def clear(self) -> None:
        self._plans.clear()


QuestionKey = tuple[State, Predicate, tuple[tuple[str, Predicate], ...], frozenset[str], int, tuple[int, bool]]


def question_key(start: State, goal: Predicate, goals: tuple[tuple[str, Predicate], ...], disabled: frozenset[str],
                 expansions: int, races: tuple[int, bool]) -> QuestionKey:
    """`goal`: what is searched for (the request's goals, or a subset of them when looking for the smallest
    unreachable one); `goals`: the request's by name in their order (the goal agenda follows it); the
    expansions the member may use; and the races learnt in time so far (`steps.TimedRaces.version`): a race
    learnt since changes what the search may answer."""
    return start, goal, goals, frozenset(disabled), expansions, races


@dataclass(frozen=True)
class SearchedAnswer:
    """What the satisficing member settled: its moves, or why the goals are unreachable, or neither (it ran
    out of its expansions), with the work it counted."""

    moves: tuple[Move, ...] | None
    proof: str | None
    expanded: int
    generated: int


class SearchMemory:
    """The satisficing member's answers by question, the newest `kept` (bounded over a shift)."""

    def __init__(self, kept: int = SEARCHES_KEPT) -> None:
        self.kept = kept
        self._answers: OrderedDict[QuestionKey, SearchedAnswer] = OrderedDict()

    def __len__(self) -> int:
        return len(self._answers)

    def remember(self, key: QuestionKey, answer: SearchedAnswer) -> None:
        self._answers[key] = answer
        self._answers.move_to_end(key)
        if len(self._answers) > self.kept:
            self._answers.popitem(last=False)

    def recall(self, key: QuestionKey) -> SearchedAnswer | None:
        found = self._answers.get(key)
        if found is not None:
            self._answers.move_to_end(key)
        return found

    def clear(self) -> None:
        self._answers.clear()
