"""`hubctl check`: is every operation's goal reachable from its precondition?"""

from __future__ import annotations

from common.model import Model
from common.model.compiled import CompiledModel, State

from .planner import Planner
from .plans import NoPlan, Plan

CHECK_TIME_LIMIT = 10.0


def _fire(compiled: CompiledModel, state: State, name: str) -> State:
    """Fire an operation transition if it is enabled (as stage 1 of the engine does), then the automatics."""
    t = compiled.by_name.get(name)
    if t is not None and t.guard(state):
        state = t.outcomes[0](state)
    state, _ = compiled.close(state)
    return state


def _why(result: NoPlan, time_limit: float) -> str:
    if result.unreachable:
        return result.reason
    return f"undecided, no plan found within {time_limit:g} s ({result.reason})"


def check_operations(
    model: Model, compiled: CompiledModel, planner: Planner, time_limit: float = CHECK_TIME_LIMIT
) -> list[str]:
    """A message for every operation whose goal is unreachable from its precondition (or undecided).

    The operations are walked in model order, as the station runs them, starting from
    the model's initial state: the planner reaches a state where the precondition
    holds (from where the previous operation ended, else from the initial state), the
    operation starts there (its start transition and actions, then the urgent
    automatics, as the engine would), and the planner looks for a plan to the goal.
    Only that first precondition state is tried. A search that runs out of time is
    reported as undecided rather than passed.
    """
    problems = []
    initial = compiled.initial()
    walk = initial
    for op in model.operations:
        before: Plan | NoPlan = NoPlan("not tried")
        for origin in dict.fromkeys((walk, initial)):
            before = planner.plan(origin, {f"{op.name} (pre)": op.pre}, time_limit=time_limit)
            if isinstance(before, Plan):
                break
        if isinstance(before, NoPlan):
            problems.append(f"operation {op.name}: its precondition {op.pre} cannot be reached from the initial "
                            f"state: {_why(before, time_limit)}")
            continue
        state = _fire(compiled, before.states[-1], f"{op.state_path}.start")
        after = planner.plan(state, {op.name: op.goal}, time_limit=time_limit)
        if isinstance(after, NoPlan):
            problems.append(f"operation {op.name}: its goal {op.goal} cannot be reached from its precondition: "
                            f"{_why(after, time_limit)}")
            continue
        walk = _fire(compiled, after.states[-1], f"{op.state_path}.finish")
    return problems
