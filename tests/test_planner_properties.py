"""Property tests: on small random models, A* plans are exactly as short as exhaustive breadth-first plans.

Random models mix all transition kinds (deliberate, automatic, multi-outcome effects), copy
actions, forbidden predicates, disabled resources and unstable start states; the heuristic
runs with random small projection caps so that its approximations (dropped variables,
nondeterministic copies, partial urgency) are exercised too.
"""

from __future__ import annotations

import random

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from common.model import (
    And,
    Const,
    Domain,
    Eq,
    In,
    IsTrue,
    Model,
    Ne,
    Not,
    Or,
    Predicate,
    Ref,
    Resource,
    Transition,
    Variable,
    ability,
    all_of,
    automatic,
    command,
    deliberate,
    effect,
    measured,
)
from common.model.actions import Assign
from common.model.compiled import CompiledModel
from common.model.variables import Value
from controller.planner import HeuristicOptions, NoPlan, Plan, Planner, breadth_first, validate_plan

DOMAINS = (Domain((False, True)), Domain.enum("a", "b", "c"), Domain.range(0, 2), Domain.enum("x", "y"))
Problem = tuple[CompiledModel, tuple, dict[str, Predicate], Predicate | None, frozenset[str], HeuristicOptions]


class Generator:
    """Random models from one `random.Random` (drawn by Hypothesis): an even spread of sizes and shapes."""

    def __init__(self, rnd: random.Random) -> None:
        self.rnd = rnd
        count = rnd.randint(2, 5)
        self.vs: list[Variable] = []
        for k in range(count):
            make = rnd.choice((command, measured))
            resource = "r" if k % 2 == 0 else "s"
            self.vs.append(make(f"{resource}.v{k}{'_c' if make is command else '_m'}", rnd.choice(DOMAINS)))

    def same(self, v: Variable) -> list[Variable]:
        return [o for o in self.vs if o.path != v.path and o.domain == v.domain]

    def literal(self, avoid: str = "") -> Predicate:
        rnd = self.rnd
        v = rnd.choice([v for v in self.vs if v.path != avoid] or self.vs)
        values = v.domain.values
        choice = rnd.randint(0, 5)
        if v.domain.is_bool and choice == 0:
            return IsTrue(v.path)
        if choice == 1 and self.same(v):
            return Eq(v.path, Ref(rnd.choice(self.same(v)).path))
        if choice == 2:
            return Ne(v.path, rnd.choice(values))
        if choice == 3 and len(values) > 2:
            return In(v.path, tuple(rnd.sample(values, 2)))
        return Eq(v.path, rnd.choice(values))

    def predicate(self, depth: int = 2) -> Predicate:
        rnd = self.rnd
        if depth == 0 or rnd.randint(0, 2) == 0:
            return Const(rnd.random() < 0.5) if rnd.randint(0, 30) == 0 else self.literal()
        kind = rnd.choice(("and", "or", "not"))
        if kind == "not":
            return Not(self.predicate(depth - 1))
        items = tuple(self.predicate(depth - 1) for _ in range(rnd.randint(2, 3)))
        return And(items) if kind == "and" else Or(items)

    def actions(self, writable: list[Variable]) -> tuple[Assign, ...]:
        rnd = self.rnd
        result = []
        for v in rnd.sample(writable, min(len(writable), rnd.randint(1, 2))):
            if self.same(v) and rnd.randint(0, 4) == 0:
                result.append(Assign(v.path, Ref(rnd.choice(self.same(v)).path)))
            else:
                result.append(Assign(v.path, rnd.choice(v.domain.values)))
        return tuple(result)

    def transition(self, n: int, phase: tuple[Variable, Value, Value] | None = None) -> Transition:
        """A random transition; `phase` = (w, a, b) makes it a phase step `w == a (&& ...) -> w := b`."""
        rnd = self.rnd
        controlled = [v for v in self.vs if not v.path.endswith("_m")]
        sensed = [v for v in self.vs if v.path.endswith("_m")]
        kinds = [k for k, ok in (("deliberate", controlled), ("automatic", controlled), ("effect", sensed)) if ok]
        kind = rnd.choice(kinds)
        if phase is not None:
            kind = "effect" if phase[0].path.endswith("_m") else rnd.choice(("deliberate", "deliberate", "automatic"))
        writable = sensed if kind == "effect" else controlled
        step: Assign | None = None
        if phase is None and rnd.randint(0, 2) == 0:
            guard = self.predicate()
        else:  # a phase step, as abilities are made of: w == a (and conditions) -> w := b
            if phase is None:
                w = rnd.choice(writable)
                a, b = rnd.sample(w.domain.values, 2)
            else:
                w, a, b = phase
            guard = all_of(Eq(w.path, a), *(self.literal(avoid=w.path) for _ in range(rnd.randint(0, 2))))
            step = Assign(w.path, b)

        def with_step(actions: tuple[Assign, ...]) -> tuple[Assign, ...]:
            return actions if step is None else (step, *(x for x in actions if x.path != step.path))

        if kind == "effect":
            outcomes = [self.actions(sensed) for _ in range(rnd.randint(1, 3))]
            outcomes[0] = with_step(outcomes[0])
            return effect(f"r.t{n}", guard, *outcomes)
        acts = with_step(self.actions(controlled))
        if kind == "automatic" and not isinstance(acts[0].value, Ref) and rnd.randint(0, 4):
            # Mostly self-disabling, as tracking abilities are; sometimes not (automatic cycles).
            guard = all_of(guard, Ne(acts[0].path, acts[0].value))
        return (deliberate if kind == "deliberate" else automatic)(f"r.t{n}", guard, acts)

    def problem(self) -> Problem:
        rnd = self.rnd
        # Phase cycles (each value of a variable leads to the next) make long plans common; then random ones.
        phases = []
        for v in self.vs:
            if rnd.random() < 0.6:
                values = v.domain.values
                phases += [(v, values[k], values[(k + 1) % len(values)]) for k in range(len(values))]
        phases = rnd.sample(phases, min(len(phases), rnd.randint(2, 8)))
        count = rnd.randint(max(3, len(phases)), 10)
        transitions = [self.transition(n, phases[n] if n < len(phases) else None) for n in range(count)]
        # The transitions belong to resource r but may touch s's variables: disabling s removes those.
        holder = ability("r.random")
        holder = type(holder)(holder.name, holder.predicates, tuple(transitions))
        resources = (
            Resource("r", tuple(v for v in self.vs if v.path.startswith("r.")), (holder,)),
            Resource("s", tuple(v for v in self.vs if v.path.startswith("s."))),
        )
        compiled = CompiledModel(Model("random", resources))
        written = [Eq(a.path, a.value) for t in transitions for o in t.outcomes for a in o
                   if not isinstance(a.value, Ref)]
        goals: dict[str, Predicate] = {}
        used: set[str] = set()
        for k in range(rnd.randint(1, 3)):
            choice = rnd.randint(0, 5)
            fresh = [g for g in written if g.path not in used]
            if choice == 0:
                goals[f"g{k}"] = self.predicate()
            elif choice == 1 or not fresh:
                goals[f"g{k}"] = self.literal()
            else:  # something a transition writes, on a variable of its own: often several steps away
                goals[f"g{k}"] = rnd.choice(fresh)
            used |= goals[f"g{k}"].paths()
        holds = compiled.predicate(all_of(*goals.values()))
        for _ in range(5):  # prefer a start where the goals do not hold yet
            start = tuple(rnd.choice(d.values) for d in compiled.domains)
            if not holds(start):
                break
        forbidden = all_of(*(self.literal() for _ in range(rnd.randint(2, 3)))) if rnd.random() < 0.4 else None
        disabled = frozenset({"s"}) if rnd.random() < 0.2 else frozenset()
        options = HeuristicOptions(cap=rnd.choice((1, 2, 4, 8, 20_000)), tours=rnd.random() < 0.8,
                                   arborescence=rnd.random() < 0.8)
        return compiled, start, goals, forbidden, disabled, options


@st.composite
def problems(draw: st.DrawFn) -> Problem:
    return Generator(draw(st.randoms(use_true_random=False))).problem()


@pytest.mark.slow
@settings(max_examples=600, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(problems())
def test_astar_is_as_short_as_breadth_first(problem: tuple) -> None:
    compiled, start, goals, forbidden, disabled, options = problem
    planner = Planner(compiled, forbidden, options=options)
    result = planner.plan(start, goals, disabled, time_limit=30.0)
    goal = all_of(*goals.values())
    baseline = breadth_first(compiled, start, goal, forbidden, disabled)
    event("no plan" if isinstance(baseline, NoPlan) else f"plan of {min(len(baseline.steps), 6)}+ steps")
    if isinstance(baseline, NoPlan):
        assert isinstance(result, NoPlan), f"A* found a plan where breadth-first found none: {result}"
        assert result.unreachable, result.reason
        assert set(result.unreachable) <= set(goals)
        return
    assert isinstance(result, Plan), f"breadth-first found {len(baseline.steps)} steps, A* none: {result.reason}"
    assert len(result.steps) == len(baseline.steps)
    validate_plan(compiled, start, result, goal, forbidden, disabled)
    validate_plan(compiled, start, baseline, goal, forbidden, disabled)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(problems())
def test_heuristic_is_admissible_along_shortest_plans(problem: tuple) -> None:
    compiled, start, goals, forbidden, disabled, options = problem
    baseline = breadth_first(compiled, start, all_of(*goals.values()), forbidden, disabled)
    if isinstance(baseline, NoPlan):
        return
    planner = Planner(compiled, forbidden, options=options)
    heuristic = planner.heuristic(tuple(goals.values()), disabled)
    heuristic.prepare(start)
    length = len(baseline.steps)
    for k, state in enumerate(baseline.states):
        assert heuristic(state) <= length - k, f"h overestimates at step {k} of {length}"


@st.composite
def stations(draw: st.DrawFn) -> tuple[CompiledModel, tuple, dict[str, Predicate], Predicate | None]:
    """A robot on a ring or line of poses, the paper's nutrunner and bolts at random poses; a random start
    reached by a random walk, so plans are long (tens of steps) and the tour bound is exercised."""
    from common.model import estimated, tracking
    from common.resources import nutrunner, ur

    rnd = draw(st.randoms(use_true_random=False))
    count = rnd.randint(2, 5)
    poses = [f"p{k}" for k in range(count)]
    moves = [(poses[k], poses[k + 1]) for k in range(count - 1)]
    if count > 2 and rnd.random() < 0.5:
        moves.append((poses[-1], poses[0]))
    bolts = rnd.randint(1, 4)
    at = [rnd.choice(poses) for _ in range(bolts)]
    states = Domain.enum("placed", "tightened")
    model = Model(
        "station",
        (ur("ur", poses, moves, poses[0]), nutrunner("nr")),
        tuple(estimated(f"engine.b{i}_e", states, "placed") for i in range(bolts)),
        tuple(tracking(f"engine.b{i}_tightened", f"engine.b{i}_e == placed && nr.tqr_m && ur.pos_m == {p}",
                       f"engine.b{i}_e := tightened") for i, p in enumerate(at)),
    )
    compiled = CompiledModel(model)
    from controller.planner.bfs import micro_steps

    state = compiled.initial()
    for _ in range(rnd.randint(0, 12)):
        steps = micro_steps(compiled, state, frozenset())
        if not steps:
            break
        t, o = rnd.choice(steps)
        state = t.outcomes[o](state)
    chosen = rnd.sample(range(bolts), rnd.randint(1, bolts))
    goals: dict[str, Predicate] = {f"bolt{i}": Eq(f"engine.b{i}_e", "tightened") for i in chosen}
    if rnd.random() < 0.3:
        goals["park"] = Eq("ur.pos_m", rnd.choice(poses))
    forbidden = None
    if rnd.random() < 0.3:  # the robot may not move while the nutrunner runs
        forbidden = And((IsTrue("nr.run_m"), Eq("ur.pos_m", "unknown")))
    return compiled, state, goals, forbidden


@pytest.mark.slow
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(stations())
def test_astar_is_as_short_as_breadth_first_on_stations(problem: tuple) -> None:
    compiled, start, goals, forbidden = problem
    result = Planner(compiled, forbidden).plan(start, goals, time_limit=30.0)
    goal = all_of(*goals.values())
    baseline = breadth_first(compiled, start, goal, forbidden)
    event("no plan" if isinstance(baseline, NoPlan) else f"plan of {len(baseline.steps) // 10 * 10}+ steps")
    if isinstance(baseline, NoPlan):
        assert isinstance(result, NoPlan)
        return
    assert isinstance(result, Plan), result.reason
    assert len(result.steps) == len(baseline.steps)
    validate_plan(compiled, start, result, goal, forbidden)
