"""The online planner: plans to a conjunction of named goals, by the portfolio of `portfolio.py` (a first
plan from greedy search, shorter ones from A* with projection heuristics, the symbolic member last).

Semantics (those of the engine, see `steps`): plans are made of ability transitions
(operation transitions are stage 1's, never planned); automatic ones are urgent and
appear in the plan; a plan ends at the first micro state where every goal holds, even
inside an automatic chain; no state on it, the start included, is forbidden;
transitions touching a disabled resource are left out. Every plan is checked by
simulation (`validate.check_plan`) before it is returned.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator, Mapping, Sequence

from common.model import Predicate, all_of
from common.model.compiled import CompiledModel, State

from .abstraction import Abstraction
from .heuristics import GoalHeuristic, HeuristicOptions
from .plans import NoPlan, Plan, PlanStats, PlanStep, moves_of
from .portfolio import Budget, PortfolioRun
from .relaxed import RelaxedModel
from .reuse import PlanMemory, SearchMemory
from .steps import Move, RaceCheck, StateTest, StepSystem, TimedRaces, stable_goal
from .stopping import StopTest
from .symbolic import SymbolicPlanner
from .validate import PlanInvalid, check_plan, plan_from_moves

MAX_SUBSET = 3  # "no plan" looks for an unreachable subset of at most this many goals, smallest first
HEURISTIC_CACHE = 128
ABSTRACTION_CACHE = 96


class Planner:
    """Plans for one compiled model and forbidden predicate; caches projections and heuristics across calls.

    `plan` may run in a worker thread; calls are serialized by a lock (the caches are shared). Its public
    methods are what a portfolio run uses (`portfolio.PlannerTables`). A table built under a stop test
    (a newer request) is stored only once built whole: a stopped request leaves every cache as it was.
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
        self.is_forbidden: StateTest | None = compiled.predicate(forbidden) if forbidden is not None else None
        self._lock = threading.Lock()
        self._predicates: dict[Predicate, Callable[[State], bool]] = {}
        self._steps: dict[tuple[int, int], PlanStep] = {}
        self._systems: dict[frozenset[str], StepSystem] = {}
        # Built once per set of disabled resources (20 ms on the reference station), shared by the search
        # and `revalidate`; a dict read or write is atomic, so the lock-free `revalidate` may use it.
        self._races: dict[frozenset[str], RaceCheck] = {}
        self.timed_races = TimedRaces()  # what plans refused in time taught (controller/loop.py)
        self._relaxed: dict[frozenset[str], RelaxedModel] = {}
        self._symbolic: dict[tuple[frozenset[str], tuple[int, bool]], SymbolicPlanner] = {}
        self._abstractions: dict[tuple[frozenset[str], tuple[int, ...], frozenset[int]], Abstraction] = {}
        self._heuristics: OrderedDict[tuple[frozenset[str], tuple[Predicate, ...]], GoalHeuristic] = OrderedDict()
        self.memory = PlanMemory(compiled)
        self.searches = SearchMemory()

    # --- caches -----------------------------------------------------------------------------
    def race_check(self, disabled: frozenset[str]) -> RaceCheck:
        race = self._races.get(disabled)
        if race is None:
            race = self._races[disabled] = RaceCheck(self.compiled, disabled, self.timed_races)
        return race

    def step_system(self, disabled: frozenset[str]) -> StepSystem:
        system = self._systems.get(disabled)
        if system is None:
            system = self._systems[disabled] = StepSystem(self.compiled, disabled, self.race_check(disabled))
        return system

    def prepare(self, disabled: frozenset[str] = frozenset()) -> float:
        """Build the tables every request needs (step system, race check, relaxed model) before the first
        one, as the controller's planner process does at start-up; returns the seconds it took."""
        began = time.perf_counter()
        self.relaxed(disabled)
        return time.perf_counter() - began

    def relaxed(self, disabled: frozenset[str]) -> RelaxedModel:
        found = self._relaxed.get(disabled)
        if found is None:
            found = self._relaxed[disabled] = RelaxedModel(self.step_system(disabled))
        return found

    def symbolic(self, disabled: frozenset[str], stop: StopTest | None = None) -> SymbolicPlanner | None:
        """The symbolic member for this set of disabled resources, built on first use (its BDD encoding
        takes a few hundred milliseconds; it is asked only when greedy and A* settled nothing)."""
        key = (disabled, self.timed_races.version)  # built again once a race is learnt: it compiles them in
        found = self._symbolic.get(key)
        if found is None:
            found = self._symbolic[key] = SymbolicPlanner(self.compiled, self.forbidden, disabled, stop,
                                                          self.timed_races.known())
        return found

    def goal_test(self, goal: Predicate) -> Callable[[State], bool]:
        is_goal = self._predicates.get(goal)
        if is_goal is None:
            if len(self._predicates) > HEURISTIC_CACHE:
                self._predicates.clear()
            is_goal = self._predicates[goal] = self.compiled.predicate(goal)
        return is_goal

    def heuristic_ready(self, goals: tuple[Predicate, ...], disabled: frozenset[str], start: State) -> bool:
        """The A* tables for these goals are built for `start` (a search from it costs no table build; a
        stopped build or preparation leaves them not ready, to be completed by the next one)."""
        heuristic = self._heuristics.get((disabled, goals))
        return heuristic is not None and heuristic.ready_for(start)

    def heuristic(self, goals: tuple[Predicate, ...], disabled: frozenset[str] = frozenset(),
                  stop: StopTest | None = None) -> GoalHeuristic:
        """A*'s heuristic for these goals, built on first use (`stop` may end the build: `stopping.Stopped`).
        Its tables for a start are built by its `prepare`."""
        key = (disabled, goals)
        h = self._heuristics.get(key)
        if h is not None:
            self._heuristics.move_to_end(key)
            return h
        system = self.step_system(disabled)

        def abstraction(variables: tuple[int, ...], costed: frozenset[int]) -> Abstraction:
            akey = (disabled, variables, costed)
            found = self._abstractions.get(akey)
            if found is None:
                if len(self._abstractions) >= ABSTRACTION_CACHE:  # memory stays bounded in a long run
                    self._abstractions.clear()
                found = self._abstractions[akey] = Abstraction(system, variables, self.forbidden, costed)
            return found

        h = GoalHeuristic(system, goals, abstraction, self.options, stop)
        self._heuristics[key] = h
        if len(self._heuristics) > HEURISTIC_CACHE:
            self._heuristics.popitem(last=False)
        return h

    def checked_plan(self, start: State, moves: Sequence[Move], goals: tuple[str, ...], stats: PlanStats,
                     is_goal: StateTest, disabled: frozenset[str]) -> Plan:
        """The moves from `start` as a plan, checked by simulation with the engine's semantics (raises
        `PlanInvalid` otherwise). The printed steps are kept across plans: printing a synthesized guard is
        not cheap."""
        plan = plan_from_moves(self.compiled, start, moves, goals, stats, self._steps)
        check_plan(self.compiled, start, plan, is_goal, self.is_forbidden, disabled, "the goals",
                   self.race_check(disabled))
        return plan

    def clear_cache(self) -> None:
        with self._lock:
            self._systems.clear()
            self._relaxed.clear()
            self._symbolic.clear()
            self._abstractions.clear()
            self._heuristics.clear()
            self.memory.clear()
            self.searches.clear()

    # --- planning -----------------------------------------------------------------------------
    def plan(
        self,
        start: State,
        goals: Mapping[str, Predicate],
        disabled: frozenset[str] = frozenset(),
        time_limit: float | None = 10.0,
        *,
        budget: Budget | None = None,
    ) -> Plan | NoPlan:
        """The best plan the portfolio finds within the budget (a shortest one where it can show it), or why
        there is none. `time_limit` (seconds) is shorthand for `Budget(seconds=time_limit)`."""
        *_, last = self.plan_anytime(start, goals, disabled, budget or Budget(seconds=time_limit))
        return last

    def plan_anytime(
        self,
        start: State,
        goals: Mapping[str, Predicate],
        disabled: frozenset[str] = frozenset(),
        budget: Budget | None = None,
    ) -> Iterator[Plan | NoPlan]:
        """The portfolio: first any valid plan (satisficing search), then strictly shorter ones (A*, then the
        symbolic member), the last one marked minimal when that was shown; or a single NoPlan.

        Every plan is checked by simulation with the engine's semantics before it is yielded.
        """
        budget = budget or Budget()
        with self._lock:
            run = PortfolioRun(self, start, tuple(goals), goals, frozenset(disabled), budget)
            for answer in run.answers():
                if isinstance(answer, Plan) and answer.steps:
                    self.memory.remember(run.key, answer)
                yield answer

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
        is_goal = stable_goal(compiled, self.goal_test(all_of(*goals.values())), disabled)
        moves = moves_of(compiled, steps)
        # The printed steps' cache is shared with the search's (a dict read or write is atomic; a step printed
        # twice by two threads is the same step).
        plan = plan_from_moves(compiled, start, moves, tuple(goals), PlanStats("revalidated"), self._steps)
        try:
            check_plan(compiled, start, plan, is_goal, self.is_forbidden, disabled, "the goals",
                       self.race_check(disabled))
        except PlanInvalid:
            return None
        return Plan(plan.steps, plan.states, plan.goals, PlanStats("revalidated", time.perf_counter() - began))
