"""A* over macro-steps with an admissible (possibly inconsistent) heuristic.

Costs are micro-steps (a macro-step costs 1 + the automatics it triggered). A goal
reached inside a chain becomes a terminal entry with f = g; the search stops when a
terminal entry is popped, which is optimal because the heuristic never overestimates.
States are reopened when reached more cheaply (the heuristic need not be consistent).
Ties on f prefer the larger g: on the long plateaus of equal f (bolts tightened in
any order) the search dives to a goal instead of widening.
"""

from __future__ import annotations

import heapq
import time
from dataclasses import dataclass
from enum import Enum
from typing import Protocol

from common.model.compiled import State

from .abstraction import INF
from .steps import Move, StateTest, StepSystem, Successor, settle
from .stopping import StopTest

# Expansions between two looks at the clock and the stop test (a system call each). An expansion evaluates
# the heuristic of every successor, up to milliseconds each where its caches are cold: a newer request
# waits at most this many expansions.
TIME_CHECK_EVERY = 4


class SearchEnd(Enum):
    """How a search (A* or greedy) ended."""

    FOUND = "found"  # its moves reach a goal
    OUT_OF_BUDGET = "out of budget"  # the expansions or the deadline ran out first
    STOPPED = "stopped"  # its stop test said so (a newer request waits)
    DEAD_END = "dead end"  # the heuristic shows no goal reachable from the start
    EXHAUSTED = "exhausted"  # every reachable state (below the bound) explored: no plan
    AUTOMATICS_AT_START = "the automatic transitions due at the start enter a forbidden state or never stop"


class Heuristic(Protocol):
    """A lower bound on the steps left (INF: no goal reachable), with tables built for the states reachable
    from a start by `prepare` (`heuristics.GoalHeuristic`)."""

    def __call__(self, state: State, /) -> int: ...
    def prepare(self, start: State, stop: StopTest | None = None) -> None: ...


@dataclass
class SearchResult:
    moves: list[Move] | None  # None: no plan, `end` says why
    end: SearchEnd
    expanded: int = 0
    generated: int = 0

    @property
    def timed_out(self) -> bool:
        """Ended before it settled anything: a plan may still exist."""
        return self.end is SearchEnd.OUT_OF_BUDGET or self.end is SearchEnd.STOPPED


def out_of_time(expanded: int, limit: int, deadline: float | None, stop: StopTest | None) -> SearchEnd | None:
    """Whether a search ends here (None: it goes on). Called every so many expansions: the clock and the stop
    test cost a system call each."""
    if expanded > limit or (deadline is not None and time.perf_counter() > deadline):
        return SearchEnd.OUT_OF_BUDGET
    if stop is not None and stop():
        return SearchEnd.STOPPED
    return None


Parents = dict[State, tuple[State, tuple[Move, ...]] | None]


def path_to(parent: Parents, state: State, last: tuple[Move, ...]) -> list[Move]:
    """The moves from the search's root to `state` (along the parent links), then `last`."""
    moves = list(last)
    while (link := parent[state]) is not None:
        state, steps = link
        moves[:0] = steps
    return moves


def astar(
    system: StepSystem,
    start: State,
    goal: StateTest,
    forbidden: StateTest | None,
    heuristic: Heuristic,
    deadline: float | None,
    *,
    bound: int = INF,
    max_expansions: int | None = None,
    stop: StopTest | None = None,
    leftovers: list[object] | None = None,
) -> SearchResult:
    """A shortest move sequence from `start` (neither forbidden nor a goal) to a goal state.

    Only plans shorter than `bound` count (an incumbent from another member): "exhausted"
    then means no plan shorter than the bound exists. `max_expansions` bounds the work
    deterministically; `deadline` (perf_counter) and `stop` (a newer request) end it early.
    A search ended by `stop` puts its open list and closed states into `leftovers` (if given):
    freeing them takes ~30 ms per second searched, which the owner spends when it has time.
    """
    settled = settle(system, start, goal, forbidden)
    if settled is None:
        return SearchResult(None, SearchEnd.AUTOMATICS_AT_START)
    if isinstance(settled, Successor):
        return SearchResult(list(settled.moves), SearchEnd.FOUND)
    root, prefix = settled
    heuristic.prepare(root, stop)  # may raise `Stopped`: a table build cut short keeps nothing half built
    h0 = heuristic(root)
    if h0 >= INF:
        return SearchResult(None, SearchEnd.DEAD_END)
    if len(prefix) + h0 >= bound:
        return SearchResult(None, SearchEnd.EXHAUSTED)
    best_g: dict[State, int] = {root: 0}
    parent: Parents = {root: None}
    h_of: dict[State, int] = {root: h0}
    counter = 0
    heap: list[tuple[int, int, int, State, tuple[State, tuple[Move, ...]] | None]] = [(h0, 0, 0, root, None)]
    best_goal = bound - len(prefix) if bound < INF else INF  # costs below count from `root`
    expanded = generated = 0
    limit = INF if max_expansions is None else max_expansions
    successors = system.successors
    push, pop = heapq.heappush, heapq.heappop
    while heap:
        _, negative_g, _, state, terminal = pop(heap)
        if terminal is not None:
            return SearchResult(prefix + path_to(parent, *terminal), SearchEnd.FOUND, expanded, generated)
        g = -negative_g
        if g > best_g[state]:
            continue  # a stale entry: reached more cheaply since
        expanded += 1
        if expanded > limit or expanded % TIME_CHECK_EVERY == 0:
            end = out_of_time(expanded, limit, deadline, stop)
            if end is not None:
                if end is SearchEnd.STOPPED and leftovers is not None:
                    leftovers.append((heap, best_g, parent, h_of))
                return SearchResult(None, end, expanded, generated)
        for succ in successors(state, goal, forbidden):
            generated += 1
            g2 = g + len(succ.moves)
            if g2 >= best_goal:
                continue
            if succ.goal:
                best_goal = g2
                counter += 1
                push(heap, (g2, -g2, counter, succ.state, (state, succ.moves)))
                continue
            s2 = succ.state
            if g2 >= best_g.get(s2, INF):
                continue
            h2 = h_of.get(s2)
            if h2 is None:
                h2 = heuristic(s2)
                h_of[s2] = h2
            if h2 >= INF or g2 + h2 >= best_goal:
                continue
            best_g[s2] = g2
            parent[s2] = (state, succ.moves)
            counter += 1
            push(heap, (g2 + h2, -g2, counter, s2, None))
    return SearchResult(None, SearchEnd.EXHAUSTED, expanded, generated)
