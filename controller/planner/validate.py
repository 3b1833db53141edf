"""Plan checking by simulation with the engine's semantics, and plan construction from moves."""

from __future__ import annotations

from collections.abc import Callable, Iterable

from common.model import Predicate, TransitionKind
from common.model.compiled import CompiledModel, CompiledTransition, State

from .plans import Plan, PlanStats, PlanStep
from .steps import RaceCheck


class PlanInvalid(ValueError):
    """A plan that the engine would not follow; `index` is the offending step (len(steps) for the end)."""

    def __init__(self, index: int, reason: str) -> None:
        self.index = index
        self.reason = reason
        super().__init__(f"plan step {index}: {reason}")


def plan_step(compiled: CompiledModel, t: CompiledTransition, outcome: int) -> PlanStep:
    actions = "; ".join(str(a) for a in t.source.outcomes[outcome])
    extra = compiled.extra_guards.get(t.name)
    return PlanStep(t.name, t.kind, outcome, str(t.source.guard), actions,
                    compiled.guard_specs.get(t.name, ("synthesized",) if extra is not None else ()),
                    "" if extra is None else str(extra))


def plan_from_moves(
    compiled: CompiledModel,
    start: State,
    moves: Iterable[tuple[int, int]],
    goals: tuple[str, ...],
    stats: PlanStats,
    cache: dict[tuple[int, int], PlanStep] | None = None,
) -> Plan:
    """Replay (transition number, outcome) moves from `start` into a Plan with its states.

    `cache` keeps the printed steps between calls: printing a synthesized guard is not cheap.
    """
    states = [start]
    steps = []
    for number, outcome in moves:
        t = compiled.transitions[number]
        states.append(t.outcomes[outcome](states[-1]))
        step = None if cache is None else cache.get((number, outcome))
        if step is None:
            step = plan_step(compiled, t, outcome)
            if cache is not None:
                cache[number, outcome] = step
        steps.append(step)
    return Plan(tuple(steps), tuple(states), goals, stats)


def validate_plan(
    compiled: CompiledModel,
    start: State,
    plan: Plan,
    goal: Predicate,
    forbidden: Predicate | None = None,
    disabled: frozenset[str] = frozenset(),
) -> None:
    """Raise PlanInvalid unless the engine, from `start`, would take exactly these steps to a goal state.

    Checks: the recorded states are the simulated ones; each step is an ability
    transition of no disabled resource whose guard (synthesized part included) holds;
    where an automatic transition is enabled the step is the first enabled one in model
    order (automatics never wait) and an automatic step is never taken otherwise; no
    command starts an effect that an effect already due would overtake (`RaceCheck`); no
    state, the start included, is forbidden; the last state satisfies the goal.
    """
    is_forbidden = compiled.predicate(forbidden) if forbidden is not None else None
    check_plan(compiled, start, plan, compiled.predicate(goal), is_forbidden, disabled, str(goal))


def check_plan(
    compiled: CompiledModel,
    start: State,
    plan: Plan,
    is_goal: Callable[[State], bool],
    is_forbidden: Callable[[State], bool] | None,
    disabled: frozenset[str],
    goal_text: str = "goal",
    race: RaceCheck | None = None,
) -> None:
    """`validate_plan` with the goal and forbidden predicates already compiled (the planner caches them)."""
    race = race or RaceCheck(compiled, disabled)
    if len(plan.states) != len(plan.steps) + 1:
        raise PlanInvalid(0, f"{len(plan.steps)} steps but {len(plan.states)} states (expected one more)")
    if plan.states[0] != start:
        raise PlanInvalid(0, "the plan does not begin at the start state")
    ability = {t.number for t in (*compiled.automatic, *compiled.deliberate, *compiled.effects)}
    state = start
    for index, step in enumerate(plan.steps):
        if is_forbidden is not None and is_forbidden(state):
            raise PlanInvalid(index, f"the state before the step is forbidden: {compiled.describe(state)}")
        t = compiled.by_name.get(step.transition)
        if t is None or t.number not in ability:
            raise PlanInvalid(index, f"{step.transition} is not an ability transition of the model")
        if t.kind is not step.kind:
            raise PlanInvalid(index, f"{step.transition} is {t.kind.value}, the plan says {step.kind.value}")
        if t.resources & disabled:
            names = ", ".join(sorted(t.resources & disabled))
            raise PlanInvalid(index, f"{t.name} touches disabled resource(s) {names}")
        if not 0 <= step.outcome < len(t.outcomes):
            raise PlanInvalid(index, f"{t.name} has no outcome {step.outcome}")
        urgent = next((a for a in compiled.automatic if not (a.resources & disabled) and a.guard(state)), None)
        if urgent is not None and urgent is not t:
            raise PlanInvalid(index, f"automatic {urgent.name} is enabled and must fire before {t.name}")
        if not t.guard(state):
            raise PlanInvalid(index, f"the guard of {t.name} does not hold: {compiled.guard_of(t.source)}")
        if t.kind is TransitionKind.DELIBERATE and race.races(state, t):
            raise PlanInvalid(index, f"{t.name} starts an effect that an effect already due would overtake")
        if t.kind is not TransitionKind.AUTOMATIC and race.outrun(state, t):
            raise PlanInvalid(index, f"{t.name} counts on an effect due that came first in time before")
        state = t.outcomes[step.outcome](state)
        if plan.states[index + 1] != state:
            raise PlanInvalid(index, "the recorded state after the step differs from the simulated one")
    if is_forbidden is not None and is_forbidden(state):
        raise PlanInvalid(len(plan.steps), f"the final state is forbidden: {compiled.describe(state)}")
    if not is_goal(state):
        raise PlanInvalid(len(plan.steps), f"the final state does not satisfy the goal {goal_text}")
    due = next((a for a in compiled.automatic if not (a.resources & disabled) and a.guard(state)), None)
    if due is not None:
        raise PlanInvalid(len(plan.steps), f"the plan ends while automatic {due.name} is due: the engine fires it "
                                           f"before it looks at the goal")
