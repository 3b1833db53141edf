"""The planner's memory of its last plan per goal set, so a request asked again costs no search.

The controller asks the same goals again when a newer request stopped the last one, when a
plan step failed and the state went back onto the plan, or when an operator retries; a
benchmark asks them twice. If the new start is a state the remembered plan passes through,
the rest of that plan from there is a plan from the start: it is handed back as moves, to be
validated by simulation like every other member's plan. The rest of a shortest plan is a
shortest plan from where it starts (a shorter one would shorten the whole), so the rest of a
plan shown minimal is minimal too.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Mapping

from common.model import Predicate
from common.model.compiled import CompiledModel, State

from .plans import Plan, moves_of
from .steps import Move

PLANS_KEPT = 64  # goal sets remembered (a run asks a few dozen)

Key = tuple[tuple[Predicate, ...], frozenset[str]]  # the goals, the disabled resources


def memory_key(goals: Mapping[str, Predicate], disabled: frozenset[str]) -> Key:
    return tuple(goals.values()), frozenset(disabled)


class PlanMemory:
    def __init__(self, compiled: CompiledModel, kept: int = PLANS_KEPT) -> None:
        self.compiled = compiled
        self.kept = kept
        self._plans: OrderedDict[Key, Plan] = OrderedDict()

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
