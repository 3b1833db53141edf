"""The online planner: shortest plans to a conjunction of named goals, by A* with projection heuristics.

Semantics (those of the engine, see `steps`): plans are made of ability transitions
(operation transitions are stage 1's, never planned); automatic ones are urgent and
appear in the plan; a plan ends at the first micro state where every goal holds, even
inside an automatic chain; no state on it, the start included, is forbidden;
transitions touching a disabled resource are left out. Every plan is checked by
simulation (`validate.check_plan`) before it is returned.
"""

from __future__ import annotations

import itertools
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from common.model import Predicate, all_of
from common.model.compiled import CompiledModel, State

from .abstraction import Abstraction
from .heuristics import GoalHeuristic, HeuristicOptions
from .plans import NoPlan, Plan, PlanStats, PlanStep
from .search import astar
from .steps import RaceCheck, StepSystem, stable_goal
from .validate import PlanInvalid, check_plan, plan_from_moves

MAX_SUBSET = 3  # "no plan" looks for an unreachable subset of at most this many goals, smallest first
HEURISTIC_CACHE = 128
ABSTRACTION_CACHE = 96


@dataclass
class _Attempt:
    result: Plan | NoPlan
    proven: bool  # NoPlan and shown unreachable (not a time-out)


def _short(predicate: Predicate, limit: int = 160) -> str:
    text = str(predicate)
    return text if len(text) <= limit else text[: limit - 3] + "..."


class Planner:
    """Plans for one compiled model and forbidden predicate; caches projections and heuristics across calls.

    `plan` may run in a worker thread; calls are serialized by a lock (the caches are shared).
    """

    def __init__(
        self,
        compiled: CompiledModel,
        forbidden: Predicate | None = None,
        *,
        options: HeuristicOptions | None = None,
        max_subset: int = MAX_SUBSET,
    ) -> None:
        self.compiled = compiled
        self.forbidden = forbidden
        self.options = options or HeuristicOptions()
        self.max_subset = max_subset
        self._is_forbidden = compiled.predicate(forbidden) if forbidden is not None else None
        self._lock = threading.Lock()
        self._predicates: dict[Predicate, Callable[[State], bool]] = {}
        self._steps: dict[tuple[int, int], PlanStep] = {}
        self._systems: dict[frozenset[str], StepSystem] = {}
        # Built once per set of disabled resources (20 ms on the reference station), shared by the search
        # and `revalidate`; a dict read or write is atomic, so the lock-free `revalidate` may use it.
        self._races: dict[frozenset[str], RaceCheck] = {}
        self._abstractions: dict[tuple[frozenset[str], tuple[int, ...], frozenset[int]], Abstraction] = {}
        self._heuristics: OrderedDict[tuple[frozenset[str], tuple[Predicate, ...]], GoalHeuristic] = OrderedDict()

    # --- caches -----------------------------------------------------------------------------
    def _race(self, disabled: frozenset[str]) -> RaceCheck:
        race = self._races.get(disabled)
        if race is None:
            race = self._races[disabled] = RaceCheck(self.compiled, disabled)
        return race

    def _system(self, disabled: frozenset[str]) -> StepSystem:
        system = self._systems.get(disabled)
        if system is None:
            system = self._systems[disabled] = StepSystem(self.compiled, disabled, self._race(disabled))
        return system

    def heuristic(self, goals: tuple[Predicate, ...], disabled: frozenset[str] = frozenset()) -> GoalHeuristic:
        key = (disabled, goals)
        h = self._heuristics.get(key)
        if h is not None:
            self._heuristics.move_to_end(key)
            return h
        system = self._system(disabled)

        def abstraction(variables: tuple[int, ...], costed: frozenset[int]) -> Abstraction:
            akey = (disabled, variables, costed)
            found = self._abstractions.get(akey)
            if found is None:
                if len(self._abstractions) >= ABSTRACTION_CACHE:  # memory stays bounded in a long run
                    self._abstractions.clear()
                found = self._abstractions[akey] = Abstraction(system, variables, self.forbidden, costed)
            return found

        h = GoalHeuristic(system, goals, abstraction, self.options)
        self._heuristics[key] = h
        if len(self._heuristics) > HEURISTIC_CACHE:
            self._heuristics.popitem(last=False)
        return h

    def clear_cache(self) -> None:
        with self._lock:
            self._systems.clear()
            self._abstractions.clear()
            self._heuristics.clear()

    # --- planning -----------------------------------------------------------------------------
    def plan(
        self,
        start: State,
        goals: Mapping[str, Predicate],
        disabled: frozenset[str] = frozenset(),
        time_limit: float = 10.0,
    ) -> Plan | NoPlan:
        """A shortest plan from `start` to a state where every goal holds, or why there is none."""
        with self._lock:
            began = time.perf_counter()
            deadline = began + time_limit
            names = tuple(goals)
            attempt = self._attempt(start, names, goals, frozenset(disabled), deadline, began)
            if isinstance(attempt.result, Plan) or not attempt.proven:
                return attempt.result
            unreachable = self._smallest_unreachable(start, names, goals, frozenset(disabled), deadline)
            result = attempt.result
            return NoPlan(result.reason, unreachable, result.stats)

    def revalidate(
        self,
        start: State,
        steps: Sequence[PlanStep],
        goals: Mapping[str, Predicate],
        disabled: frozenset[str] = frozenset(),
    ) -> Plan | None:
        """The rest of a plan replayed from a state it did not predict: the same steps if the engine would
        still take them to the goals (the camera saw the operator leave where nothing waits for that), else
        None. Takes no lock (it reads only the race checks' dict), so it may run beside a search in another thread."""
        began = time.perf_counter()
        compiled = self.compiled
        is_goal = stable_goal(compiled, compiled.predicate(all_of(*goals.values())), disabled)
        moves = [(compiled.by_name[step.transition].number, step.outcome) for step in steps]
        plan = plan_from_moves(compiled, start, moves, tuple(goals), PlanStats("revalidated"))
        try:
            check_plan(compiled, start, plan, is_goal, self._is_forbidden, disabled, "the goals",
                       self._race(disabled))
        except PlanInvalid:
            return None
        return Plan(plan.steps, plan.states, plan.goals, PlanStats("revalidated", time.perf_counter() - began))

    def _attempt(
        self,
        start: State,
        names: tuple[str, ...],
        goals: Mapping[str, Predicate],
        disabled: frozenset[str],
        deadline: float,
        began: float,
    ) -> _Attempt:
        compiled = self.compiled
        goal = all_of(*(goals[n] for n in names))
        is_goal = self._predicates.get(goal)
        if is_goal is None:
            if len(self._predicates) > HEURISTIC_CACHE:
                self._predicates.clear()
            is_goal = self._predicates[goal] = compiled.predicate(goal)

        def stats(method: str, expanded: int = 0, generated: int = 0, build: float = 0.0) -> PlanStats:
            return PlanStats(method, time.perf_counter() - began, expanded, generated, build)

        if self._is_forbidden is not None and self._is_forbidden(start):
            return _Attempt(NoPlan(f"the start state is forbidden ({_short(self.forbidden)})",  # type: ignore[arg-type]
                                   names, stats("none")), False)
        is_goal = stable_goal(compiled, is_goal, disabled)
        if is_goal(start):
            return _Attempt(Plan((), (start,), names, stats("trivial")), False)
        build_began = time.perf_counter()
        heuristic = self.heuristic(tuple(goals[n] for n in names), disabled)
        heuristic.prepare(start)  # tables over the abstract states reachable from here (cached if unchanged)
        build = time.perf_counter() - build_began
        system = self._system(disabled)
        found = astar(system, start, is_goal, self._is_forbidden, heuristic, deadline)
        if found.moves is not None:
            plan = plan_from_moves(compiled, start, found.moves, names,
                                   stats("astar", found.expanded, found.generated, build), self._steps)
            try:
                check_plan(compiled, start, plan, is_goal, self._is_forbidden, disabled, "the goals", system.race)
            except PlanInvalid as exc:  # a planner bug: never hand such a plan to the engine
                return _Attempt(NoPlan(f"internal error, the plan failed validation: {exc}", (),
                                       plan.stats), False)
            return _Attempt(plan, False)
        final = stats("astar", found.expanded, found.generated, build)
        if found.timed_out:
            return _Attempt(NoPlan(f"no plan found within the time limit ({found.expanded} states expanded)", (),
                                   final), False)
        if found.reason == "heuristic":
            reason = f"{', '.join(names)}: {heuristic.why_unreachable(start)}"
        elif found.reason == "exhausted":
            reason = f"{', '.join(names)}: unreachable ({found.expanded} reachable states explored)"
        else:
            reason = f"{', '.join(names)}: {found.reason}"
        if disabled:
            reason += f" (disabled resources left out: {', '.join(sorted(disabled))})"
        return _Attempt(NoPlan(reason, names, final), True)

    def _smallest_unreachable(
        self,
        start: State,
        names: tuple[str, ...],
        goals: Mapping[str, Predicate],
        disabled: frozenset[str],
        deadline: float,
    ) -> tuple[str, ...]:
        """Singletons first, then pairs, ...: the first subset shown unreachable (bounded in size and time)."""
        for size in range(1, min(len(names), self.max_subset + 1)):
            for subset in itertools.combinations(names, size):
                if time.perf_counter() > deadline:
                    return names
                attempt = self._attempt(start, subset, goals, disabled, deadline, time.perf_counter())
                if attempt.proven:
                    return subset
        return names
