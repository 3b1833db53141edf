"""Satisficing search: lazy greedy best-first over macro-steps with the relaxed-plan heuristic
and preferred moves (the Fast Downward recipe: two open lists, preferred successors boosted).

Why this member answers first where A* stalls: the states that blow A* up are
interleavings of moves that do not matter to the goal (the operator confirming, the
camera, the nutrunner resetting in the operator's hand). Such a move is never in the
relaxed plan, so it is never preferred, and the search follows the preferred moves
straight to a goal; the plain list keeps the search complete. A state is evaluated
when it is taken from a list, not when it is generated (lazy), so a wide state costs
one heuristic evaluation, not one per successor.

Work is counted in expansions (deterministic: a seed reproduces a run on any
machine); a wall-clock deadline may stop it earlier.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable

from common.model.compiled import State

from .abstraction import INF
from .relaxed import Estimate
from .search import Parents, SearchEnd, SearchResult, out_of_time, path_to
from .steps import Move, StateTest, StepSystem, Successor, settle

BOOST = 1000  # expansions from the preferred list after each new best h
CHECK_EVERY = 8  # an expansion evaluates a relaxed plan (milliseconds): look at the clock often


def greedy(
    system: StepSystem,
    start: State,
    goal: StateTest,
    forbidden: StateTest | None,
    evaluate: Callable[[State], Estimate],
    *,
    max_expansions: int,
    deadline: float | None = None,
    stop: Callable[[], bool] | None = None,
) -> SearchResult:
    """Some move sequence from `start` (not forbidden, not a goal) to a goal state, or why none was found."""
    settled = settle(system, start, goal, forbidden)
    if settled is None:
        return SearchResult(None, SearchEnd.AUTOMATICS_AT_START)
    if isinstance(settled, Successor):
        return SearchResult(list(settled.moves), SearchEnd.FOUND)
    root, prefix = settled
    parent: Parents = {}
    # entries: (h of the parent, order, state, its parent link)
    Entry = tuple[int, int, State, tuple[State, tuple[Move, ...]] | None]
    lists: tuple[list[Entry], list[Entry]] = ([], [])  # preferred, all
    order = 0
    lists[1].append((0, 0, root, None))
    best_h = INF
    priority = 0  # > 0: take from the preferred list
    turn = 0
    expanded = generated = 0
    pop, push = heapq.heappop, heapq.heappush
    while lists[0] or lists[1]:
        if lists[0] and (priority > 0 or not lists[1] or turn % 2 == 0):
            which = 0
            priority -= 1
        else:
            which = 1
        turn += 1
        _, _, state, link = pop(lists[which])
        if state in parent:
            continue
        parent[state] = link
        estimate = evaluate(state)
        if estimate.h >= INF:
            continue
        expanded += 1
        if expanded > max_expansions or expanded % CHECK_EVERY == 0:
            end = out_of_time(expanded, max_expansions, deadline, stop)
            if end is not None:
                return SearchResult(None, end, expanded, generated)
        if estimate.h < best_h:
            best_h = estimate.h
            priority = BOOST
        preferred = estimate.preferred
        preferred |= system.unblocking(state, preferred)
        for succ in system.successors(state, goal, forbidden):
            generated += 1
            if succ.goal:
                return SearchResult(prefix + path_to(parent, state, succ.moves), SearchEnd.FOUND, expanded, generated)
            if succ.state in parent:
                continue
            order += 1
            entry = (estimate.h, order, succ.state, (state, succ.moves))
            if succ.moves[0] in preferred:
                push(lists[0], entry)
            push(lists[1], entry)
    # Nothing expanded: the root itself is a dead end of the relaxation.
    return SearchResult(None, SearchEnd.EXHAUSTED if expanded else SearchEnd.DEAD_END, expanded, generated)
