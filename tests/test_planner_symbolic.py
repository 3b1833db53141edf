"""The symbolic planner member: as short as breadth-first and A*, valid by the plan check, exact semantics.

Every plan found is replayed by `check_plan` (the engine's semantics, RaceCheck included);
on small random models the BDD move sets, images and preimages are compared state by state
with `bfs.micro_steps`, an independent implementation of the same semantics.
"""

from __future__ import annotations

import itertools
import time

import pytest
from hypothesis import HealthCheck, given, settings

from common.model import Model, Predicate, all_of, parse_predicate
from common.model.compiled import CompiledModel, State
from controller.planner import NoPlan, Plan, Planner, breadth_first
from controller.planner import symbolic_encoding as symbolic_module
from controller.planner.bfs import micro_steps
from controller.planner.plans import PlanStats
from controller.planner.steps import RaceCheck, stable_goal
from controller.planner.symbolic import SymbolicPlanner, SymbolicResult
from controller.planner.validate import check_plan, plan_from_moves
from tests import test_planner as examples
from tests import test_planner_properties as properties
from tests.stations import synthetic


def checked(
    compiled: CompiledModel,
    start: State,
    goal: Predicate,
    result: SymbolicResult,
    forbidden: Predicate | None = None,
    disabled: frozenset[str] = frozenset(),
) -> Plan:
    """The result as a Plan, after the engine-semantics check every planner's plans pass."""
    assert result.moves is not None, result.reason
    assert result.layers == len(result.moves)
    plan = plan_from_moves(compiled, start, result.moves, ("goal",), PlanStats("symbolic"))
    is_goal = stable_goal(compiled, compiled.predicate(goal), disabled)
    is_forbidden = compiled.predicate(forbidden) if forbidden is not None else None
    check_plan(compiled, start, plan, is_goal, is_forbidden, disabled, str(goal), RaceCheck(compiled, disabled))
    return plan


def names(compiled: CompiledModel, result: SymbolicResult) -> list[str]:
    assert result.moves is not None, result.reason
    return [compiled.transitions[number].name for number, _ in result.moves]


# --- small hand-made models --------------------------------------------------------------------
def test_nutrunner_plan_is_the_papers_sequence() -> None:
    compiled = CompiledModel(Model("nr", (examples.nutrunner(),)))
    planner = SymbolicPlanner(compiled, None)
    goal = parse_predicate("nr.tqr_m")
    result = planner.search(compiled.initial(), goal)
    checked(compiled, compiled.initial(), goal, result)
    assert names(compiled, result) == ["nr.tighten.enabled", "nr.tighten.starting.effect",
                                       "nr.tighten.executing.effect", "nr.tighten.finished"]
    assert not result.proven_unreachable and not result.timed_out
    failing = planner.search(compiled.initial(), parse_predicate("nr.fail_m"))
    checked(compiled, compiled.initial(), parse_predicate("nr.fail_m"), failing)
    assert failing.moves is not None and failing.moves[2][1] == 1  # the failure outcome of the effect


def test_goal_already_true_is_an_empty_plan() -> None:
    compiled = CompiledModel(Model("nr", (examples.nutrunner(),)))
    result = SymbolicPlanner(compiled, None).search(compiled.initial(), parse_predicate("!nr.run_c"))
    assert result.moves == [] and result.layers == 0


def test_transient_goal_is_proven_unreachable() -> None:
    """Torque with the command still set exists only while an automatic is due: never a stable goal."""
    compiled = CompiledModel(Model("nr", (examples.nutrunner(),)))
    result = SymbolicPlanner(compiled, None).search(compiled.initial(), parse_predicate("nr.tqr_m && nr.run_c"))
    assert result.moves is None and result.proven_unreachable and not result.timed_out
    assert "unreachable" in result.reason
    assert isinstance(breadth_first(compiled, compiled.initial(), parse_predicate("nr.tqr_m && nr.run_c")), NoPlan)


def test_disabled_resources_are_left_out() -> None:
    model = examples.bolt_model(1)
    compiled = CompiledModel(model)
    goal = model.operations[0].goal
    without_robot = SymbolicPlanner(compiled, None, frozenset({"ur"}))
    assert without_robot.search(compiled.initial(), goal).proven_unreachable
    torque = parse_predicate("nr.tqr_m")
    result = without_robot.search(compiled.initial(), torque)
    checked(compiled, compiled.initial(), torque, result, disabled=frozenset({"ur"}))
    assert all(not name.startswith("ur.") for name in names(compiled, result))


def test_plan_never_relies_on_an_automatic_transition_waiting() -> None:
    compiled = CompiledModel(examples.waiting_model())
    goal = parse_predicate("a.done_c")
    result = SymbolicPlanner(compiled, None).search(compiled.initial(), goal)
    checked(compiled, compiled.initial(), goal, result)
    assert names(compiled, result) == ["a.slow1", "a.slow2"]


def test_forbidden_states_are_avoided() -> None:
    compiled = CompiledModel(examples.detour_model())
    goal, forbidden = parse_predicate("a.x == 3"), parse_predicate("a.x == 2")
    free = SymbolicPlanner(compiled, None).search(compiled.initial(), goal)
    careful = SymbolicPlanner(compiled, forbidden).search(compiled.initial(), goal)
    checked(compiled, compiled.initial(), goal, free)
    checked(compiled, compiled.initial(), goal, careful, forbidden)
    assert names(compiled, free) == ["a.inc0", "a.inc1", "a.inc2"]
    assert names(compiled, careful) == ["a.prep1", "a.prep2", "a.prep3", "a.jump"]


def test_forbidden_start_is_no_plan() -> None:
    model = examples.bolt_model(1)
    compiled = CompiledModel(model)
    result = SymbolicPlanner(compiled, parse_predicate("ur.pos_m == p0")).search(
        compiled.initial(), model.operations[0].goal)
    assert result.moves is None and "forbidden" in result.reason
    assert not result.proven_unreachable and not result.timed_out  # as Planner: not a proof about the goal


def test_a_command_never_races_an_effect_under_way() -> None:
    compiled = CompiledModel(examples.robot_and_gripper())
    goal = parse_predicate("g.held_m && r.away_m")
    result = SymbolicPlanner(compiled, None).search(compiled.initial(), goal)
    checked(compiled, compiled.initial(), goal, result)
    steps = names(compiled, result)
    assert len(steps) == 4
    assert steps.index("g.grab.executing.effect") < steps.index("r.leave.enabled")
    # From the state after the grab command, sending the robot off races the grab: never the next move.
    after_grab = compiled.transitions[compiled.by_name["g.grab.enabled"].number].outcomes[0](compiled.initial())
    leave = compiled.by_name["r.leave.enabled"]
    assert RaceCheck(compiled).races(after_grab, leave)
    planner = SymbolicPlanner(compiled, None)
    enc = planner.encoding
    fire = next(m.fire for m in planner.moves if m.number == leave.number)
    assert enc.state(after_grab) & fire == enc.false
    assert enc.state(compiled.initial()) & fire != enc.false


def test_unstable_start_fires_the_automatics_first() -> None:
    compiled = CompiledModel(examples.bolt_model(1))
    start = compiled.with_values(compiled.initial(), {"nr.run_c": True, "nr.run_m": True, "nr.tqr_m": True,
                                                      "ur.pos_m": "p1", "ur.ref_c": "p1"})
    goal = parse_predicate("!nr.run_m")
    result = SymbolicPlanner(compiled, None).search(start, goal)
    checked(compiled, start, goal, result)
    assert names(compiled, result) == ["nr.tighten.finished", "engine.bolt1_tightened",
                                       "nr.tighten.resetting.effect"]


# --- as short as breadth-first and A* ---------------------------------------------------------
def test_synthetic_station_as_short_as_breadth_first_and_astar() -> None:
    model = synthetic.build_model(4)
    compiled = CompiledModel(model)
    planner = SymbolicPlanner(compiled, None)
    astar = Planner(compiled)
    start = compiled.initial()
    goals = {op.name: op.goal for op in model.operations}
    cases = [*({name: goal} for name, goal in goals.items()), goals]
    for case in cases:
        goal = all_of(*case.values())
        result = planner.search(start, goal)
        checked(compiled, start, goal, result)
        baseline = breadth_first(compiled, start, goal)
        reference = astar.plan(start, case)
        assert isinstance(baseline, Plan) and isinstance(reference, Plan)
        assert len(result.moves or ()) == len(baseline.steps) == len(reference.steps), list(case)


def test_kept_backward_layers_give_shortest_plans_from_other_starts() -> None:
    """Replanning from states along a plan reuses the goal's backward layers; plans stay shortest."""
    model = examples.bolt_model(3)
    compiled = CompiledModel(model)
    goal = all_of(*(op.goal for op in model.operations))
    planner = SymbolicPlanner(compiled, None)
    first = planner.search(compiled.initial(), goal)
    plan = checked(compiled, compiled.initial(), goal, first)
    kept = first.backward
    for state in plan.states[1::3]:
        again = planner.search(state, goal)
        checked(compiled, state, goal, again)
        baseline = breadth_first(compiled, state, goal)
        assert isinstance(baseline, Plan) and len(again.moves or ()) == len(baseline.steps)
        assert again.backward >= kept  # the layers were kept, not rebuilt
    planner.clear_cache()
    assert planner.search(compiled.initial(), goal).moves == first.moves  # deterministic from a fresh cache


def test_plans_are_deterministic() -> None:
    model = synthetic.build_model(3)
    compiled = CompiledModel(model)
    goal = all_of(*(op.goal for op in model.operations))
    one = SymbolicPlanner(compiled, None).search(compiled.initial(), goal)
    two = SymbolicPlanner(compiled, None).search(compiled.initial(), goal)
    assert one.moves == two.moves and one.moves is not None


# --- budgets -------------------------------------------------------------------------------------
def test_budgets_end_the_search_without_a_proof() -> None:
    model = synthetic.build_model(4)
    compiled = CompiledModel(model)
    goal = all_of(*(op.goal for op in model.operations))
    planner = SymbolicPlanner(compiled, None)
    by_layers = planner.search(compiled.initial(), goal, max_layers=5)
    assert by_layers.moves is None and by_layers.timed_out and not by_layers.proven_unreachable
    assert by_layers.layers == 5 and "5 layers" in by_layers.reason
    planner.clear_cache()
    by_nodes = planner.search(compiled.initial(), goal, max_nodes=50)
    assert by_nodes.moves is None and by_nodes.timed_out and "nodes" in by_nodes.reason
    planner.clear_cache()
    by_clock = planner.search(compiled.initial(), goal, deadline=time.perf_counter() - 1)
    assert by_clock.moves is None and by_clock.timed_out and "time limit" in by_clock.reason
    # An interrupted search leaves nothing half done: the next one finds the shortest plan.
    full = planner.search(compiled.initial(), goal)
    checked(compiled, compiled.initial(), goal, full)
    assert len(full.moves or ()) == 20


# --- exact semantics on random models --------------------------------------------------------
def all_states(compiled: CompiledModel) -> list[State]:
    return list(itertools.product(*(d.values for d in compiled.domains)))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(properties.problems())
def test_move_sets_images_and_preimages_are_the_engines(problem: properties.Problem) -> None:
    """State by state: each move's set is where micro_steps offers it (urgency, guards, RaceCheck), and
    the image and preimage of a single state are its successors and predecessors."""
    compiled, _, _, forbidden, disabled, _ = problem
    planner = SymbolicPlanner(compiled, forbidden, disabled)
    enc = planner.encoding
    race = RaceCheck(compiled, disabled)
    states = all_states(compiled)
    predecessors: dict[State, set[State]] = {s: set() for s in states}
    for state in states:
        cube = enc.state(state)
        offered = {(t.number, o) for t, o in micro_steps(compiled, state, disabled, race)}
        fired = {(m.number, m.outcome) for m in planner.moves if cube & m.fire != enc.false}
        assert fired == offered, compiled.describe(state)
        successors = {compiled.transitions[n].outcomes[o](state) for n, o in offered}
        image = planner._image(cube)
        expected = enc.false
        for s in successors:
            expected |= enc.state(s)
            predecessors[s].add(state)
        assert image == expected, compiled.describe(state)
    for state in states[:: max(1, len(states) // 40)]:
        expected = enc.false
        for s in predecessors[state]:
            expected |= enc.state(s)
        assert planner._preimage(enc.state(state)) & enc.valid == expected, compiled.describe(state)


@pytest.mark.slow
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(properties.problems())
def test_as_short_as_breadth_first_on_random_models(problem: properties.Problem) -> None:
    compiled, start, goals, forbidden, disabled, _ = problem
    goal = all_of(*goals.values())
    result = SymbolicPlanner(compiled, forbidden, disabled).search(start, goal)
    baseline = breadth_first(compiled, start, goal, forbidden, disabled)
    assert not result.timed_out
    if isinstance(baseline, NoPlan):
        assert result.moves is None
        if "forbidden" in baseline.reason:
            assert "forbidden" in result.reason
        else:
            assert result.proven_unreachable, result.reason
        return
    checked(compiled, start, goal, result, forbidden, disabled)
    assert len(result.moves or ()) == len(baseline.steps)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(properties.stations())
def test_as_short_as_breadth_first_on_random_stations(problem: tuple) -> None:
    compiled, start, goals, forbidden = problem
    goal = all_of(*goals.values())
    result = SymbolicPlanner(compiled, forbidden).search(start, goal)
    baseline = breadth_first(compiled, start, goal, forbidden)
    if isinstance(baseline, NoPlan):
        assert result.moves is None and (result.proven_unreachable or "forbidden" in result.reason)
        return
    checked(compiled, start, goal, result, forbidden)
    assert len(result.moves or ()) == len(baseline.steps)


# --- the pure-Python fallback -------------------------------------------------------------------------
def test_pure_python_backend_gives_the_same_plans(monkeypatch: pytest.MonkeyPatch) -> None:
    from dd import autoref

    compiled = CompiledModel(examples.bolt_model(2))
    goal = all_of(*(op.goal for op in examples.bolt_model(2).operations))
    fast = SymbolicPlanner(compiled, None).search(compiled.initial(), goal)
    monkeypatch.setattr(symbolic_module, "_dd", autoref)
    monkeypatch.setattr(symbolic_module, "BACKEND", "autoref")
    slow = SymbolicPlanner(compiled, None).search(compiled.initial(), goal)
    checked(compiled, compiled.initial(), goal, slow)
    assert slow.moves == fast.moves
    race_model = CompiledModel(examples.robot_and_gripper())
    race_goal = parse_predicate("g.held_m && r.away_m")
    checked(race_model, race_model.initial(), race_goal,
            SymbolicPlanner(race_model, None).search(race_model.initial(), race_goal))
