"""Exhaustive breadth-first search over micro-steps: the baseline and the oracle for optimality tests.

Written directly against `CompiledModel` (compiled guards, model order of the
automatic transitions), independently of the A* machinery, so that the property
tests compare two separate implementations of the same semantics.
"""

from __future__ import annotations

import time

from common.model import Predicate
from common.model.compiled import CompiledModel, CompiledTransition, State

from .plans import NoPlan, Plan, PlanStats
from .steps import RaceCheck, stable_goal
from .validate import plan_from_moves

DEFAULT_LIMIT_STATES = 2_000_000


def micro_steps(
    compiled: CompiledModel, state: State, disabled: frozenset[str], race: RaceCheck | None = None
) -> list[tuple[CompiledTransition, int]]:
    """The steps possible in `state` under the engine's semantics (urgent automatics, no racing command)."""
    for t in compiled.automatic:
        if not (t.resources & disabled) and t.guard(state):
            return [(t, 0)]
    race = race or RaceCheck(compiled, disabled)
    steps: list[tuple[CompiledTransition, int]] = []
    for t in compiled.deliberate:
        if not (t.resources & disabled) and t.guard(state) and not race.races(state, t):
            steps.extend((t, o) for o in range(len(t.outcomes)))
    for t in compiled.effects:
        if not (t.resources & disabled) and t.guard(state):
            steps.extend((t, o) for o in range(len(t.outcomes)))
    return steps


def breadth_first(
    compiled: CompiledModel,
    start: State,
    goal: Predicate,
    forbidden: Predicate | None = None,
    disabled: frozenset[str] = frozenset(),
    limit_states: int = DEFAULT_LIMIT_STATES,
    goals: tuple[str, ...] = ("goal",),
) -> Plan | NoPlan:
    """A shortest plan by plain breadth-first search, or NoPlan (also when `limit_states` is exceeded)."""
    began = time.perf_counter()
    is_goal = stable_goal(compiled, compiled.predicate(goal), disabled)
    is_forbidden = compiled.predicate(forbidden) if forbidden is not None else None

    def stats(expanded: int, generated: int) -> PlanStats:
        return PlanStats("bfs", time.perf_counter() - began, expanded, generated)

    if is_forbidden is not None and is_forbidden(start):
        return NoPlan("the start state is forbidden", stats=stats(0, 0))
    race = RaceCheck(compiled, disabled)
    parent: dict[State, tuple[State, int, int] | None] = {start: None}
    frontier = [start]
    expanded = generated = 0
    found: State | None = start if is_goal(start) else None
    while frontier and found is None:
        next_frontier: list[State] = []
        for state in frontier:
            expanded += 1
            for t, o in micro_steps(compiled, state, disabled, race):
                after = t.outcomes[o](state)
                generated += 1
                if after in parent or (is_forbidden is not None and is_forbidden(after)):
                    continue
                parent[after] = (state, t.number, o)
                if is_goal(after):
                    found = after
                    break
                next_frontier.append(after)
            if found is not None:
                break
            if len(parent) > limit_states:
                return NoPlan(f"breadth-first search gave up after {limit_states} states", stats=stats(expanded,
                                                                                                    generated))
        frontier = next_frontier
    if found is None:
        return NoPlan(f"unreachable: all {len(parent)} reachable states explored", stats=stats(expanded, generated))
    moves: list[tuple[int, int]] = []
    state = found
    while (link := parent[state]) is not None:
        state, number, outcome = link
        moves.append((number, outcome))
    moves.reverse()
    return plan_from_moves(compiled, start, moves, goals, stats(expanded, generated))
