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
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from common.model import Predicate, all_of
from common.model.compiled import State

from .abstraction import INF
from .greedy import greedy
from .plans import NoPlan, Plan, PlanStats, moves_of
from .search import SearchResult, astar
from .shorten import eliminate, without_loops
from .steps import Move, stable_goal
from .validate import PlanInvalid, check_plan, plan_from_moves

if TYPE_CHECKING:
    from .planner import Planner

ELIMINATION_FIRST = 4_000  # steps simulated while taking detours out of a first plan (about 40 ms)
ELIMINATION_MORE = 100_000  # and again, before A*, when there is time to improve it
AGENDA_FROM = 2  # goals from which the satisficing member first tries them one after another


@dataclass(frozen=True)
class Budget:
    """How much search one request may spend.

    `first_expansions`: the satisficing member; `improve_expansions`: A* below the first plan's
    length (0: keep the first plan); `symbolic_layers`: breadth-first layers of the symbolic
    member; `seconds`: wall clock for the first answer, `improve_seconds` for the improvement
    (None: no clock, only counts — virtual time); `hold_seconds`: how long the first answer may
    wait for a warm A* to return a shortest plan instead; `stop`: a newer request is waiting.
    """

    first_expansions: int = 20_000
    improve_expansions: int = 20_000
    symbolic_layers: int = 2_000
    seconds: float | None = None
    improve_seconds: float | None = None
    hold_seconds: float | None = None
    stop: Callable[[], bool] | None = None


def _short(predicate: Predicate, limit: int = 160) -> str:
    text = str(predicate)
    return text if len(text) <= limit else text[: limit - 3] + "..."


class _Run:
    def __init__(self, planner: Planner, start: State, names: tuple[str, ...], goals: Mapping[str, Predicate],
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
        self.build = 0.0
        self.first_seconds = 0.0
        self.first_length = -1

    # --- helpers -------------------------------------------------------------------------------
    def _deadline(self, seconds: float | None) -> float | None:
        return None if seconds is None else time.perf_counter() + seconds

    def _stats(self, method: str, minimal: bool = False) -> PlanStats:
        return PlanStats(method, time.perf_counter() - self.began, self.expanded, self.generated, self.build,
                         minimal, self.first_seconds, self.first_length)

    def _count(self, found: SearchResult) -> None:
        self.expanded += found.expanded
        self.generated += found.generated

    def _plan(self, moves: list[Move], method: str, minimal: bool, is_goal: Callable[[State], bool]) -> Plan | NoPlan:
        planner = self.planner
        plan = plan_from_moves(planner.compiled, self.start, moves, self.names, self._stats(method, minimal),
                               planner._steps)
        try:
            check_plan(planner.compiled, self.start, plan, is_goal, planner._is_forbidden, self.disabled,
                       "the goals", planner._race(self.disabled))
        except PlanInvalid as exc:  # a planner bug: never hand such a plan to the engine
            return NoPlan(f"internal error, the {method} plan failed validation: {exc}", (), plan.stats)
        return plan

    def _disabled_note(self) -> str:
        return f" (disabled resources left out: {', '.join(sorted(self.disabled))})" if self.disabled else ""

    # --- the portfolio -----------------------------------------------------------------------------
    def answers(self) -> Iterator[Plan | NoPlan]:
        planner, budget, start = self.planner, self.budget, self.start
        compiled = planner.compiled
        goal = all_of(*(self.goals[n] for n in self.names))
        if planner._is_forbidden is not None and planner._is_forbidden(start):
            yield NoPlan(f"the start state is forbidden ({_short(planner.forbidden)})",  # type: ignore[arg-type]
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
                    tuple(self.goals[n] for n in self.names), self.disabled):
                # Warm A* tables: a shortest plan may be a few milliseconds away; answer with it if so,
                # rather than with a longer plan the station starts to follow at once.
                better, _ = self._astar(goal, is_goal, incumbent, self.began + budget.hold_seconds)
                if better is not None:
                    yield better
                    return
            yield incumbent
            moves = moves_of(self.planner.compiled, incumbent.steps)
            shorter = self._shortened(moves, is_goal, start, ELIMINATION_MORE)
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
                   work: int = ELIMINATION_FIRST) -> list[Move]:
        """A greedy plan minus its loops, then minus the detours action elimination finds."""
        planner = self.planner
        return eliminate(planner._system(self.disabled), without_loops(planner.compiled, moves, start), start,
                         is_goal, planner._is_forbidden, work)

    def _agenda(self, expansions: int, deadline: float | None) -> list[Move] | None:
        """The goals one after another (FF's goal agenda): each search keeps the goals reached so far and
        adds the next one, so its relaxed plans stay short however many goals there are. None when a
        stage fails (it may have chosen an intermediate state from which the rest cannot be reached)."""
        planner = self.planner
        system = planner._system(self.disabled)
        relaxed = planner.relaxed(self.disabled)
        state, moves, reached = self.start, [], []
        spent = 0
        for name in self.names:
            reached.append(self.goals[name])
            goal = all_of(*reached)
            is_goal = stable_goal(planner.compiled, planner.goal_test(goal), self.disabled)
            if is_goal(state):
                continue
            found = greedy(system, state, is_goal, planner._is_forbidden, relaxed.goal(goal).evaluate,
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
        """(a plan or None, None) or (None, why the goals are unreachable)."""
        planner = self.planner
        if len(self.names) >= AGENDA_FROM:
            before = self.expanded
            moves = self._agenda(expansions // 2, deadline)
            if moves is not None:
                moves = self._shortened(moves, is_goal, self.start)
                return self._plan(moves, "greedy", False, is_goal), None
            expansions -= self.expanded - before
        system = planner._system(self.disabled)
        relaxed = planner.relaxed(self.disabled).goal(goal)
        found = greedy(system, self.start, is_goal, planner._is_forbidden, relaxed.evaluate,
                       max_expansions=expansions, deadline=deadline, stop=self.budget.stop)
        self._count(found)
        if found.moves is not None:
            moves = self._shortened(found.moves, is_goal, self.start)
            return self._plan(moves, "greedy", False, is_goal), None
        if found.timed_out:
            return None, None
        if found.reason == "heuristic":
            return None, "not reachable even when every value, once reached, is kept (relaxed planning graph)"
        if found.reason == "exhausted":
            return None, f"unreachable ({found.expanded} reachable states explored)"
        return None, found.reason

    def _astar(self, goal: Predicate, is_goal: Callable[[State], bool], incumbent: Plan | None,
               deadline: float | None = None) -> tuple[Plan | NoPlan | None, str | None]:
        """A shorter plan than the incumbent (minimal), the incumbent shown minimal, or a proof of no plan."""
        planner, budget = self.planner, self.budget
        if budget.improve_expansions <= 0 or (budget.stop is not None and budget.stop()):
            return None, None
        build_began = time.perf_counter()
        heuristic = planner.heuristic(tuple(self.goals[n] for n in self.names), self.disabled)
        heuristic.prepare(self.start)
        self.build += time.perf_counter() - build_began
        bound = len(incumbent.steps) if incumbent is not None else INF
        seconds = budget.improve_seconds if incumbent is not None else budget.seconds
        found = astar(planner._system(self.disabled), self.start, is_goal, planner._is_forbidden, heuristic,
                      deadline or self._deadline(seconds), bound=bound, max_expansions=budget.improve_expansions,
                      stop=budget.stop)
        self._count(found)
        if found.moves is not None:
            return self._plan(found.moves, "astar", True, is_goal), None
        if found.timed_out:
            return None, None
        if incumbent is not None:  # no plan below the incumbent's length: it is a shortest one
            return replace(incumbent, stats=self._stats(incumbent.stats.method, minimal=True)), None
        if found.reason == "heuristic":
            return None, heuristic.why_unreachable(self.start)
        if found.reason == "exhausted":
            return None, f"unreachable ({found.expanded} reachable states explored)"
        return None, found.reason

    def _symbolic(self, goal: Predicate, is_goal: Callable[[State], bool]) -> Plan | NoPlan | None:
        symbolic = self.planner.symbolic(self.disabled)
        if symbolic is None:
            return None
        budget = self.budget
        found = symbolic.search(self.start, goal, max_layers=budget.symbolic_layers,
                                deadline=self._deadline(budget.improve_seconds or budget.seconds))
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
