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
from collections.abc import Callable
from dataclasses import dataclass

from common.model.compiled import State

from .abstraction import INF
from .steps import Move, StateTest, StepSystem, Successor, settle

TIME_CHECK_EVERY = 256
AUTOMATICS_AT_START = "the automatic transitions due at the start enter a forbidden state or never stop"


@dataclass
class SearchResult:
    moves: list[Move] | None  # None: no plan
    expanded: int = 0
    generated: int = 0
    timed_out: bool = False
    reason: str = ""


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
    heuristic: Callable[[State], int],
    deadline: float | None,
    *,
    bound: int = INF,
    max_expansions: int | None = None,
    stop: Callable[[], bool] | None = None,
) -> SearchResult:
    """A shortest move sequence from `start` (neither forbidden nor a goal) to a goal state.

    Only plans shorter than `bound` count (an incumbent from another member): "exhausted"
    then means no plan shorter than the bound exists. `max_expansions` bounds the work
    deterministically; `deadline` (perf_counter) and `stop` (a newer request) end it early.
    """
    settled = settle(system, start, goal, forbidden)
    if settled is None:
        return SearchResult(None, reason=AUTOMATICS_AT_START)
    if isinstance(settled, Successor):
        return SearchResult(list(settled.moves))
    root, prefix = settled
    prepare = getattr(heuristic, "prepare", None)
    if prepare is not None:
        prepare(root)
    h0 = heuristic(root)
    if h0 >= INF:
        return SearchResult(None, reason="heuristic")
    if len(prefix) + h0 >= bound:
        return SearchResult(None, reason="exhausted")
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
            return SearchResult(prefix + path_to(parent, *terminal), expanded, generated)
        g = -negative_g
        if g > best_g[state]:
            continue  # a stale entry: reached more cheaply since
        expanded += 1
        if expanded > limit or (expanded % TIME_CHECK_EVERY == 0 and (
                (deadline is not None and time.perf_counter() > deadline) or (stop is not None and stop()))):
            return SearchResult(None, expanded, generated, timed_out=True)
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
    return SearchResult(None, expanded, generated, reason="exhausted")
