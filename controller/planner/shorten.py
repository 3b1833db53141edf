"""Taking the detours out of a satisficing plan: loop removal, then action elimination.

Greedy plans carry detours: the robot sent somewhere and back before the door opens,
a move the relaxed plan wanted that the real plan never needed. Both passes keep a plan
valid under the engine's semantics (the plan check confirms it before use), and both
count their work in simulated steps, so the same request gets the same plan on any
machine.
"""

from __future__ import annotations

from collections.abc import Callable

from common.model import TransitionKind
from common.model.compiled import CompiledModel, State

from .steps import Move, StepSystem
from .stopping import StopTest, check_stop

ENOUGH_SKIPPED = 48  # micro steps a removal may drop before the attempt is taken as hopeless


def without_loops(compiled: CompiledModel, moves: list[Move], start: State) -> list[Move]:
    """The moves minus every stretch that comes back to a state it passed. What is left passes
    the same states in the same order, so it is as valid as the whole."""
    transitions = compiled.transitions
    kept: list[Move] = []
    state = start
    seen = {state: 0}
    for number, outcome in moves:
        state = transitions[number].outcomes[outcome](state)
        back = seen.get(state)
        if back is not None:
            del kept[back:]
            seen = {s: i for s, i in seen.items() if i <= back}
            continue
        kept.append((number, outcome))
        seen[state] = len(kept)
    return kept


def eliminate(system: StepSystem, moves: list[Move], start: State, is_goal: Callable[[State], bool],
              forbidden: Callable[[State], bool] | None, work: int, stop: StopTest | None = None) -> list[Move]:
    """Action elimination (Nakhost & Müller): drop a deliberate step and every later step that can
    no longer fire; keep the shorter plan if it still reaches the goals. An attempt ends early
    both ways: once the shortened run is back in a state the plan passed at the same point (the
    rest of the plan is valid from there, unchanged), and once it has dropped more steps than a
    detour has (the step was needed). `work` bounds the simulated steps; `stop` ends the passes
    between two attempts (`stopping.Stopped`)."""
    transitions = system.compiled.transitions
    race = system.race

    def trajectory(state: State, moves: list[Move]) -> list[State]:
        states = [state]
        for number, outcome in moves:
            states.append(transitions[number].outcomes[outcome](states[-1]))
        return states

    def replay(i: int) -> list[Move] | None:
        """The plan without step i, or None."""
        nonlocal work
        state, kept, skipped = states[i], moves[:i], 0
        for j in range(i + 1, len(moves)):
            work -= 1
            if state == states[j]:
                return kept + moves[j:]  # back on the plan's own path
            number, outcome = moves[j]
            t = transitions[number]
            due = system.first_automatic(state)
            if due is not None and due is not t:
                return None  # an automatic would fire first: dropping the step broke the chain
            if (not t.guard(state) or (t.kind is TransitionKind.DELIBERATE and race.races(state, t))
                    or (t.kind is not TransitionKind.AUTOMATIC and race.outrun(state, t))):
                skipped += 1
                if skipped > ENOUGH_SKIPPED:
                    return None
                continue
            after = t.outcomes[outcome](state)
            if forbidden is not None and forbidden(after):
                return None
            kept.append((number, outcome))
            state = after
        if is_goal(state) and system.first_automatic(state) is None:
            return kept
        return None

    states = trajectory(start, moves)
    i = 0
    while i < len(moves) and work > 0:
        check_stop(stop)
        if transitions[moves[i][0]].kind is TransitionKind.DELIBERATE:
            tried = replay(i)
            if tried is not None and len(tried) < len(moves):
                moves = tried
                states = states[:i] + trajectory(states[i], moves[i:])
                continue
        i += 1
    return moves
