"""One plan request run through the planner portfolio, anytime.

Members, in order:

1. **greedy** (satisficing: `greedy.py`, relaxed-plan heuristic, preferred moves) answers
   first with some valid plan, or shows the goals unreachable (its relaxation proves dead
   ends, its search is complete);
2. **A*** (`search.py`, admissible projection heuristics) looks for a plan shorter than
   the first; when it runs out of states below that length, the first plan is minimal;
3. **symbolic** (`symbolic.py`, breadth-first over sets of states as BDDs) is asked when
   the two above neither found a plan nor settled that there is none.

Every plan is checked by simulation with the engine's semantics before it is yielded.
Work is bounded by expansion counts (deterministic: what virtual time uses, so a seed
reproduces a run) and, live, by wall-clock seconds and a `stop` test (a newer request).
A stop ends the run at the next safe point (`stopping.py`): a search returns, a table build
keeps nothing half built, and the run yields nothing more (a NoPlan if it had yielded nothing).

A run uses its planner through `PlannerTables`: the model, its forbidden-state test, and the
tables the planner keeps per set of disabled resources across requests.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Protocol

from common.model import Predicate, all_of
from common.model.compiled import CompiledModel, State

from .abstraction import INF
from .greedy import greedy
from .heuristics import GoalHeuristic
from .plans import NoPlan, Plan, PlanStats, moves_of
from .relaxed import RelaxedModel
from .reuse import PlanMemory, SearchedAnswer, SearchMemory, question_key
from .search import SearchEnd, SearchResult, astar
from .shorten import eliminate, without_loops
from .steps import Move, StateTest, StepSystem, TimedRaces, stable_goal
from .stopping import Stopped, StopTest
from .symbolic import SymbolicPlanner
from .validate import PlanInvalid

ELIMINATION_FIRST = 4_000  # steps simulated while taking detours out of a first plan (about 40 ms)
ELIMINATION_MORE = 100_000  # and again, before A*, when there is time to improve it
RETIME_TRIES = 256  # orders the member improving a plan by time checks (0.13 s on a plan of 240 steps)
AGENDA_FROM = 2  # goals from which the satisficing member first tries them one after another


@dataclass(frozen=True)
class Budget:
    """How much search one request may spend.

    `first_expansions`: the satisficing member; `improve_expansions`: A* below the first plan's
    length (0: keep the first plan); `symbolic_layers`: breadth-first layers of the symbolic
    member; `seconds`: wall clock for the first answer, `improve_seconds` for the improvement
    (None: no clock, only counts — virtual time); `hold_seconds`: how long the first answer may
    wait for a warm A* to return a shortest plan instead; `stop`: a newer request is waiting
    (the run ends at its next safe point); `leftovers`: where A* stopped by `stop` leaves its
    tables, for the owner to free when it has time (freeing them is not instant). `retime_tries`: sequences
    the member that improves a plan by time checks (controller/retime.py; 0: none), run by the controller, which
    knows the durations and its engine's order.
    """

    first_expansions: int = 20_000
    improve_expansions: int = 20_000
    symbolic_layers: int = 2_000
    seconds: float | None = None
    improve_seconds: float | None = None
    hold_seconds: float | None = None
    stop: StopTest | None = None
    leftovers: list[object] | None = None
    retime_tries: int = RETIME_TRIES


class PlannerTables(Protocol):
    """What a portfolio run uses of its planner (`planner.Planner`): the model, its forbidden-state test, and
    the tables kept across requests. A table built with a `stop` test is stored only once it is whole."""

    compiled: CompiledModel
    forbidden: Predicate | None
    is_forbidden: StateTest | None  # `forbidden` compiled; None: nothing is forbidden
    memory: PlanMemory
    searches: SearchMemory  # the satisficing member's answers by question
    timed_races: TimedRaces  # the races plans lost in time: a search's answer depends on them
    max_subset: int

    def step_system(self, disabled: frozenset[str]) -> StepSystem: ...
    def relaxed(self, disabled: frozenset[str]) -> RelaxedModel: ...
    def goal_test(self, goal: Predicate) -> StateTest: ...
    def heuristic_ready(self, goals: tuple[Predicate, ...], disabled: frozenset[str], start: State) -> bool: ...
    def heuristic(self, goals: tuple[Predicate, ...], disabled: frozenset[str] = frozenset(),
                  stop: StopTest | None = None) -> GoalHeuristic: ...
    def symbolic(self, disabled: frozenset[str], stop: StopTest | None = None) -> SymbolicPlanner | None: ...
    def checked_plan(self, start: State, moves: Sequence[Move], goals: tuple[str, ...], stats: PlanStats,
                     is_goal: StateTest, disabled: frozenset[str]) -> Plan: ...


def _short(predicate: Predicate, limit: int = 160) -> str:
    text = str(predicate)
    return text if len(text) <= limit else text[: limit - 3] + "..."


class PortfolioRun:
    """One request: `answers()` yields its plans, each shorter than the last, or a single NoPlan."""

    def __init__(self, planner: PlannerTables, start: State, names: tuple[str, ...], goals: Mapping[str, Predicate],
                 disabled: frozenset[str], budget: Budget) -> None:
        self.planner = planner
        self.start = start
        self.names = names
        self.goals = goals
        self.disabled = disabled
        self.budget = budget
        self.key = (tuple(goals[n] for n in names), disabled)  # what the planner's memory knows the goals by
        self.began = time.perf_counter()
        self.expanded = 0
        self.generated = 0
        self.out_of_budget = False  # a search ran out of its expansions or its clock
        self.build = 0.0
        self.first_seconds = 0.0
        self.first_length = -1
        self.answered = False

    # --- helpers -------------------------------------------------------------------------------
    def _deadline(self, seconds: float | None) -> float | None:
        return None if seconds is None else time.perf_counter() + seconds

    def _stats(self, method: str, minimal: bool = False) -> PlanStats:
        return PlanStats(method, time.perf_counter() - self.began, self.expanded, self.generated, self.build,
                         minimal, self.first_seconds, self.first_length)

    def _count(self, found: SearchResult) -> None:
        """Add a search's work to the run's; a search ended by the stop test ends the run."""
        self.expanded += found.expanded
        self.generated += found.generated
        if found.end is SearchEnd.STOPPED:
            raise Stopped
        if found.end is SearchEnd.OUT_OF_BUDGET:
            self.out_of_budget = True

    def _plan(self, moves: list[Move], method: str, minimal: bool, is_goal: Callable[[State], bool]) -> Plan | NoPlan:
        stats = self._stats(method, minimal)
        try:
            return self.planner.checked_plan(self.start, moves, self.names, stats, is_goal, self.disabled)
        except PlanInvalid as exc:  # a planner bug: never hand such a plan to the engine
            return NoPlan(f"internal error, the {method} plan failed validation: {exc}", (), stats)

    def _disabled_note(self) -> str:
        return f" (disabled resources left out: {', '.join(sorted(self.disabled))})" if self.disabled else ""

    # --- the portfolio -----------------------------------------------------------------------------
    def answers(self) -> Iterator[Plan | NoPlan]:
        try:
            for answer in self._answers():
                self.answered = True
                yield answer
        except Stopped:  # at a safe point: nothing half built is left behind
            if not self.answered:
                yield NoPlan(f"{', '.join(self.names)}: stopped by a newer request before a plan was found",
                             (), self._stats("portfolio"))

    def _answers(self) -> Iterator[Plan | NoPlan]:
        planner, budget, start = self.planner, self.budget, self.start
        compiled = planner.compiled
        goal = all_of(*(self.goals[n] for n in self.names))
        if planner.is_forbidden is not None and planner.is_forbidden(start):
            yield NoPlan(f"the start state is forbidden ({_short(planner.forbidden)})",  # type: ignore[arg-type]  # the start state is forbidden only when a specification holds
                         self.names, self._stats("none"))
            return
        is_goal = stable_goal(compiled, planner.goal_test(goal), self.disabled)
        if is_goal(start):
            yield Plan((), (start,), self.names, self._stats("trivial", minimal=True))
            return
        first: Plan | NoPlan | None = self._recalled(is_goal)
        proof = None
        if first is None:
            first, proof = self._greedy(goal, is_goal, budget.first_expansions, self._deadline(budget.seconds))
        elif first.stats.minimal:
            yield first
            return
        if proof is not None:
            yield self._unreachable(proof)
            return
        incumbent: Plan | None = None
        if first is not None:
            if isinstance(first, NoPlan):
                yield first
                return
            self.first_seconds, self.first_length = first.stats.seconds, len(first.steps)
            incumbent = replace(first, stats=self._stats(first.stats.method))
            if budget.improve_expansions <= 0:
                yield incumbent
                return
            if budget.hold_seconds is not None and self.planner.heuristic_ready(
                    tuple(self.goals[n] for n in self.names), self.disabled, start):
                # Warm A* tables: a shortest plan may be a few milliseconds away; answer with it if so,
                # rather than with a longer plan the station starts to follow at once.
                try:
                    better, _ = self._astar(goal, is_goal, incumbent, self.began + budget.hold_seconds)
                except Stopped:  # the first answer is the plan in hand
                    better = None
                if better is not None:
                    yield better
                    return
            yield incumbent
            moves = moves_of(self.planner.compiled, incumbent.steps)
            shorter = self._shortened(moves, is_goal, start, ELIMINATION_MORE, budget.stop)
            if len(shorter) < len(moves):
                plan = self._plan(shorter, "greedy", False, is_goal)
                if isinstance(plan, Plan):
                    incumbent = plan
                    yield incumbent
        better, proof = self._astar(goal, is_goal, incumbent)
        if better is not None:
            yield better
            return
        if proof is not None:
            yield self._unreachable(proof)
            return
        if incumbent is not None:
            return  # A* ran out of budget: the first plan stands, not shown minimal
        symbolic = self._symbolic(goal, is_goal)
        if symbolic is not None:
            yield symbolic
            return
        yield NoPlan(f"{', '.join(self.names)}: no plan found within the budget ({self.expanded} states expanded, "
                     f"{time.perf_counter() - self.began:.1f} s); not shown unreachable, retried later"
                     + self._disabled_note(), (), self._stats("portfolio"))

    def _recalled(self, is_goal: Callable[[State], bool]) -> Plan | None:
        """The rest of the plan last found for these goals, when the start is on it (`reuse.py`), validated."""
        found = self.planner.memory.recall(self.key, self.start)
        if found is None:
            return None
        plan = self._plan(found[0], "reused", found[1], is_goal)
        return plan if isinstance(plan, Plan) else None

    def _shortened(self, moves: list[Move], is_goal: Callable[[State], bool], start: State,
                   work: int = ELIMINATION_FIRST, stop: StopTest | None = None) -> list[Move]:
        """A greedy plan minus its loops, then minus the detours action elimination finds."""
        planner = self.planner
        return eliminate(planner.step_system(self.disabled), without_loops(planner.compiled, moves, start), start,
                         is_goal, planner.is_forbidden, work, stop)

    def _agenda(self, expansions: int, deadline: float | None) -> list[Move] | None:
        """The goals one after another (FF's goal agenda): each search keeps the goals reached so far and
        adds the next one, so its relaxed plans stay short however many goals there are. None when a
        stage fails (it may have chosen an intermediate state from which the rest cannot be reached)."""
        planner = self.planner
        system = planner.step_system(self.disabled)
        relaxed = planner.relaxed(self.disabled)
        state, moves, reached = self.start, [], []
        spent = 0
        for name in self.names:
            reached.append(self.goals[name])
            goal = all_of(*reached)
            is_goal = stable_goal(planner.compiled, planner.goal_test(goal), self.disabled)
            if is_goal(state):
                continue
            found = greedy(system, state, is_goal, planner.is_forbidden, relaxed.goal(goal).evaluate,
                           max_expansions=expansions - spent, deadline=deadline, stop=self.budget.stop)
            self._count(found)
            spent += found.expanded
            if found.moves is None:
                return None
            moves += found.moves
            for number, outcome in found.moves:
                state = planner.compiled.transitions[number].outcomes[outcome](state)
        return moves

    def _greedy(self, goal: Predicate, is_goal: Callable[[State], bool], expansions: int,
                deadline: float | None) -> tuple[Plan | NoPlan | None, str | None]:
        """(a plan or None, None) or (None, why the goals are unreachable): what the member settled for this
        question before (`reuse.SearchMemory`), else its search."""
        key = question_key(self.start, goal, tuple((n, self.goals[n]) for n in self.names), self.disabled,
                           expansions, self.planner.timed_races.version)
        known = self.planner.searches.recall(key)
        if known is None:
            expanded, generated = self.expanded, self.generated
            moves, proof = self._search_greedy(goal, is_goal, expansions, deadline)
            known = SearchedAnswer(None if moves is None else tuple(moves), proof, self.expanded - expanded,
                                   self.generated - generated)
            if deadline is None or not self.out_of_budget:  # the clock may have cut it short: not repeatable
                self.planner.searches.remember(key, known)
        else:
            self.expanded += known.expanded
            self.generated += known.generated
        if known.moves is not None:
            return self._plan(list(known.moves), "greedy", False, is_goal), None
        return None, known.proof

    def _search_greedy(self, goal: Predicate, is_goal: Callable[[State], bool], expansions: int,
                       deadline: float | None) -> tuple[list[Move] | None, str | None]:
        """(the moves found, None), (None, why the goals are unreachable) or (None, None): out of budget."""
        planner = self.planner
        if len(self.names) >= AGENDA_FROM:
            before = self.expanded
            moves = self._agenda(expansions // 2, deadline)
            if moves is not None:
                return self._shortened(moves, is_goal, self.start), None
            expansions -= self.expanded - before
        system = planner.step_system(self.disabled)
        relaxed = planner.relaxed(self.disabled).goal(goal)
        found = greedy(system, self.start, is_goal, planner.is_forbidden, relaxed.evaluate,
                       max_expansions=expansions, deadline=deadline, stop=self.budget.stop)
        self._count(found)
        if found.moves is not None:
            return self._shortened(found.moves, is_goal, self.start), None
        if found.timed_out:
            return None, None
        if found.end is SearchEnd.DEAD_END:
            return None, "not reachable even when every value, once reached, is kept (relaxed planning graph)"
        if found.end is SearchEnd.EXHAUSTED:
            return None, f"unreachable ({found.expanded} reachable states explored)"
        return None, found.end.value

    def _astar(self, goal: Predicate, is_goal: Callable[[State], bool], incumbent: Plan | None,
               deadline: float | None = None) -> tuple[Plan | NoPlan | None, str | None]:
        """A shorter plan than the incumbent (minimal), the incumbent shown minimal, or a proof of no plan."""
        planner, budget = self.planner, self.budget
        if budget.improve_expansions <= 0 or (budget.stop is not None and budget.stop()):
            return None, None
        build_began = time.perf_counter()
        try:
            heuristic = planner.heuristic(tuple(self.goals[n] for n in self.names), self.disabled, budget.stop)
            heuristic.prepare(self.start, budget.stop)
        finally:
            self.build += time.perf_counter() - build_began
        bound = len(incumbent.steps) if incumbent is not None else INF
        seconds = budget.improve_seconds if incumbent is not None else budget.seconds
        found = astar(planner.step_system(self.disabled), self.start, is_goal, planner.is_forbidden, heuristic,
                      deadline or self._deadline(seconds), bound=bound, max_expansions=budget.improve_expansions,
                      stop=budget.stop, leftovers=budget.leftovers)
        self._count(found)
        if found.moves is not None:
            return self._plan(found.moves, "astar", True, is_goal), None
        if found.timed_out:
            return None, None
        if incumbent is not None:  # no plan below the incumbent's length: it is a shortest one
            return replace(incumbent, stats=self._stats(incumbent.stats.method, minimal=True)), None
        if found.end is SearchEnd.DEAD_END:
            return None, heuristic.why_unreachable(self.start)
        if found.end is SearchEnd.EXHAUSTED:
            return None, f"unreachable ({found.expanded} reachable states explored)"
        return None, found.end.value

    def _symbolic(self, goal: Predicate, is_goal: Callable[[State], bool]) -> Plan | NoPlan | None:
        budget = self.budget
        symbolic = self.planner.symbolic(self.disabled, budget.stop)
        if symbolic is None:
            return None
        found = symbolic.search(self.start, goal, max_layers=budget.symbolic_layers,
                                deadline=self._deadline(budget.improve_seconds or budget.seconds), stop=budget.stop)
        if found.stopped:
            raise Stopped
        if found.moves is not None:
            return self._plan(found.moves, "symbolic", True, is_goal)
        if found.proven_unreachable:
            return self._unreachable(f"unreachable (symbolic search: {found.reason or 'no state left to explore'})")
        return None

    # --- no plan -------------------------------------------------------------------------------
    def _unreachable(self, why: str) -> NoPlan:
        reason = f"{', '.join(self.names)}: {why}{self._disabled_note()}"
        return NoPlan(reason, self._smallest_unreachable(), self._stats("portfolio"), proven=True)

    def _smallest_unreachable(self) -> tuple[str, ...]:
        """Singletons first, then pairs, ...: the first subset the satisficing member shows unreachable."""
        names, planner = self.names, self.planner
        deadline = self._deadline(self.budget.seconds)
        per_subset = max(100, self.budget.first_expansions // 20)
        for size in range(1, min(len(names), planner.max_subset + 1)):
            for subset in itertools.combinations(names, size):
                if deadline is not None and time.perf_counter() > deadline:
                    return names
                goal = all_of(*(self.goals[n] for n in subset))
                is_goal = stable_goal(planner.compiled, planner.goal_test(goal), self.disabled)
                if is_goal(self.start):
                    continue
                _, proof = self._greedy(goal, is_goal, per_subset, deadline)
                if proof is not None:
                    return subset
        return names
