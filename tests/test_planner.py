"""The planner: the paper's nutrunner, urgency, forbidden states, disabled resources, no-plan reasons, checks."""

from __future__ import annotations

import dataclasses

import pytest

from common.model import (
    Domain,
    Model,
    Phase,
    Resource,
    TransitionKind,
    ability,
    all_of,
    automatic,
    command,
    deliberate,
    effect,
    estimated,
    measured,
    operation,
    parse_predicate,
    tracking,
)
from common.model.compiled import CompiledModel
from controller.planner import (
    NoPlan,
    Plan,
    PlanInvalid,
    Planner,
    breadth_first,
    check_operations,
    validate_plan,
)


def nutrunner() -> Resource:
    """The paper's Example 4, spelled out here so that the test does not depend on common.resources."""
    tighten = ability(
        "nr.tighten",
        enabled=Phase("!nr.run_c && !nr.run_m", deliberate="nr.run_c := true"),
        starting=Phase("nr.run_c && !nr.run_m", effects=["nr.run_m := true"]),
        executing=Phase("nr.run_c && nr.run_m && !nr.tqr_m && !nr.fail_m",
                        effects=["nr.tqr_m := true", "nr.fail_m := true"]),
        finished=Phase("nr.run_c && nr.run_m && (nr.tqr_m || nr.fail_m)", automatic="nr.run_c := false"),
        resetting=Phase("!nr.run_c && nr.run_m",
                        effects=[["nr.run_m := false", "nr.tqr_m := false", "nr.fail_m := false"]]),
    )
    variables = (command("nr.run_c"), measured("nr.run_m"), measured("nr.tqr_m"), measured("nr.fail_m"))
    return Resource("nr", variables, (tighten,))


def robot(poses: int = 4) -> Resource:
    """A robot on a line of poses, one step each way (a deliberate command, then the arrival effect)."""
    names = [f"p{k}" for k in range(poses)]
    domain = Domain.enum(*names)
    transitions = []
    for k, name in enumerate(names):
        for other in (k - 1, k + 1):
            if 0 <= other < poses:
                at_rest = f"ur.pos_m == {name} && ur.ref_c == {name}"
                transitions.append(deliberate(f"ur.go_{name}_{names[other]}", at_rest, f"ur.ref_c := {names[other]}"))
        transitions.append(effect(f"ur.arrive_{name}", f"ur.ref_c == {name} && ur.pos_m != {name}",
                                  f"ur.pos_m := {name}"))
    moves = dataclasses.replace(ability("ur.move"), transitions=tuple(transitions))
    return Resource("ur", (command("ur.ref_c", domain, "p0"), measured("ur.pos_m", domain, "p0")), (moves,))


def bolt_model(bolts: int = 2, specs: tuple = ()) -> Model:
    states = Domain.enum("placed", "tightened")
    variables = tuple(estimated(f"engine.bolt{i}_e", states, "placed") for i in range(1, bolts + 1))
    trackers = tuple(
        tracking(f"engine.bolt{i}_tightened", f"engine.bolt{i}_e == placed && nr.tqr_m && ur.pos_m == p{i}",
                 f"engine.bolt{i}_e := tightened")
        for i in range(1, bolts + 1)
    )
    ops = tuple(operation(f"TightenBolt{i}", True, f"engine.bolt{i}_e == tightened") for i in range(1, bolts + 1))
    return Model("bolts", (robot(bolts + 2), nutrunner()), variables, trackers, ops, specs)


def names(plan: Plan) -> list[str]:
    return [s.transition for s in plan.steps]


def test_nutrunner_plan_is_the_papers_sequence() -> None:
    model = Model("nr", (nutrunner(),))
    compiled = CompiledModel(model)
    planner = Planner(compiled)
    plan = planner.plan(compiled.initial(), {"torque": parse_predicate("nr.tqr_m")})
    assert isinstance(plan, Plan)
    # The paper's three steps, then the urgent automatic one: the engine fires it before it looks
    # at the goal, so the plan includes it (a plan never relies on an automatic transition waiting).
    assert names(plan) == ["nr.tighten.enabled", "nr.tighten.starting.effect", "nr.tighten.executing.effect",
                           "nr.tighten.finished"]
    assert [s.outcome for s in plan.steps] == [0, 0, 0, 0]
    assert plan.steps[-1].kind is TransitionKind.AUTOMATIC
    assert str(plan.steps[0]) == "nr.tighten.enabled [deliberate] when !nr.run_c && !nr.run_m -> nr.run_c := true"
    assert plan.states[0] == compiled.initial() and len(plan.states) == 5
    assert plan.goals == ("torque",)
    text = plan.explain(compiled)
    assert "1." in text and "4." in text and "nr.run_c := false" in text
    # Torque with the command still set exists only in a transient state: no plan may stop there.
    transient = planner.plan(compiled.initial(), {"torque": parse_predicate("nr.tqr_m && nr.run_c")})
    assert isinstance(transient, NoPlan) and transient.unreachable == ("torque",)


def test_failure_outcome_is_a_separate_choice() -> None:
    compiled = CompiledModel(Model("nr", (nutrunner(),)))
    plan = Planner(compiled).plan(compiled.initial(), {"fail": parse_predicate("nr.fail_m")})
    assert isinstance(plan, Plan)
    assert plan.steps[-2].transition == "nr.tighten.executing.effect" and plan.steps[-2].outcome == 1
    assert plan.steps[-1].transition == "nr.tighten.finished"


def test_goal_already_true_is_an_empty_plan() -> None:
    compiled = CompiledModel(Model("nr", (nutrunner(),)))
    plan = Planner(compiled).plan(compiled.initial(), {"idle": parse_predicate("!nr.run_c")})
    assert isinstance(plan, Plan) and plan.steps == () and plan.states == (compiled.initial(),)


def waiting_model() -> Model:
    """Waiting for `a.flag_c` to stay set would be shorter, but an automatic transition clears it at once."""
    variables = (command("a.flag_c"), command("a.done_c"), command("a.spare_c"))
    transitions = (
        deliberate("a.set", "!a.flag_c && !a.done_c", "a.flag_c := true"),
        automatic("a.clear", "a.flag_c", "a.flag_c := false"),
        deliberate("a.finish_with_flag", "a.flag_c", "a.done_c := true"),
        deliberate("a.slow1", "!a.spare_c", "a.spare_c := true"),
        deliberate("a.slow2", "a.spare_c && !a.done_c", "a.done_c := true"),
    )
    resource = Resource("a", variables, (dataclasses.replace(ability("a.x"), transitions=transitions),))
    return Model("waiting", (resource,))


def test_plan_never_relies_on_an_automatic_transition_waiting() -> None:
    compiled = CompiledModel(waiting_model())
    goal = parse_predicate("a.done_c")
    plan = Planner(compiled).plan(compiled.initial(), {"done": goal})
    assert isinstance(plan, Plan)
    # set + finish_with_flag (2 steps) would need a.clear to wait; the valid plan is slow1 + slow2.
    assert names(plan) == ["a.slow1", "a.slow2"]
    validate_plan(compiled, compiled.initial(), plan, goal)
    start = compiled.initial()
    waiting = Plan(
        tuple(dataclasses.replace(plan.steps[0], transition=n) for n in ("a.set", "a.finish_with_flag")),
        (start, compiled.with_values(start, {"a.flag_c": True}),
         compiled.with_values(start, {"a.flag_c": True, "a.done_c": True})),
        ("done",),
    )
    with pytest.raises(PlanInvalid, match=r"a\.clear is enabled"):
        validate_plan(compiled, start, waiting, goal)


def test_bolts_and_moves_shortest_and_equal_to_breadth_first() -> None:
    model = bolt_model(2)
    compiled = CompiledModel(model)
    goals = {op.name: op.goal for op in model.operations}
    plan = Planner(compiled).plan(compiled.initial(), goals)
    assert isinstance(plan, Plan)
    baseline = breadth_first(compiled, compiled.initial(), all_of(*goals.values()))
    assert isinstance(baseline, Plan)
    assert len(plan.steps) == len(baseline.steps)
    validate_plan(compiled, compiled.initial(), plan, all_of(*goals.values()))
    assert plan.stats.minimal and plan.stats.expanded > 0


def detour_model() -> Model:
    """a.x counts 0..3 one step at a time; a longer way (three preparations and a jump) skips a.x == 2."""
    x = command("a.x", Domain.range(0, 3), 0)
    transitions = [deliberate(f"a.inc{k}", f"a.x == {k}", f"a.x := {k + 1}") for k in range(3)]
    transitions += [deliberate(f"a.prep{k}", f"a.p == {k - 1}", f"a.p := {k}") for k in range(1, 4)]
    transitions.append(deliberate("a.jump", "a.p == 3 && a.x == 0", "a.x := 3"))
    p = command("a.p", Domain.range(0, 3), 0)
    resource = Resource("a", (x, p), (dataclasses.replace(ability("a.x"), transitions=tuple(transitions)),))
    return Model("detour", (resource,))


def test_forbidden_states_are_avoided() -> None:
    compiled = CompiledModel(detour_model())
    goal = {"three": parse_predicate("a.x == 3")}
    forbidden = parse_predicate("a.x == 2")
    free = Planner(compiled).plan(compiled.initial(), goal)
    careful = Planner(compiled, forbidden).plan(compiled.initial(), goal)
    assert isinstance(free, Plan) and isinstance(careful, Plan)
    assert names(free) == ["a.inc0", "a.inc1", "a.inc2"]
    assert names(careful) == ["a.prep1", "a.prep2", "a.prep3", "a.jump"]
    validate_plan(compiled, compiled.initial(), careful, goal["three"], forbidden)
    with pytest.raises(PlanInvalid, match="forbidden"):
        validate_plan(compiled, compiled.initial(), free, goal["three"], forbidden)
    baseline = breadth_first(compiled, compiled.initial(), goal["three"], forbidden)
    assert isinstance(baseline, Plan) and len(baseline.steps) == 4


def test_forbidden_start_is_no_plan() -> None:
    model = bolt_model(1)
    compiled = CompiledModel(model)
    planner = Planner(compiled, parse_predicate("ur.pos_m == p0"))
    result = planner.plan(compiled.initial(), {"TightenBolt1": model.operations[0].goal})
    assert isinstance(result, NoPlan) and "forbidden" in result.reason


def test_disabled_resources_are_left_out() -> None:
    model = bolt_model(1)
    compiled = CompiledModel(model)
    planner = Planner(compiled)
    goal = {"TightenBolt1": model.operations[0].goal}
    result = planner.plan(compiled.initial(), goal, disabled=frozenset({"ur"}))
    assert isinstance(result, NoPlan)
    assert result.unreachable == ("TightenBolt1",) and "ur" in result.reason
    # Without the robot, the nutrunner alone still reaches its torque.
    torque = planner.plan(compiled.initial(), {"torque": parse_predicate("nr.tqr_m")}, disabled=frozenset({"ur"}))
    assert isinstance(torque, Plan) and all(not s.transition.startswith("ur.") for s in torque.steps)
    # Even with the robot already at p1: the bolt's tracking reads the robot's pose, so it is left out too.
    at_bolt = compiled.with_values(compiled.initial(), {"ur.pos_m": "p1", "ur.ref_c": "p1"})
    assert isinstance(planner.plan(at_bolt, goal, disabled=frozenset({"ur"})), NoPlan)
    plan = planner.plan(at_bolt, goal)
    assert isinstance(plan, Plan) and all(not s.transition.startswith("ur.") for s in plan.steps)
    validate_plan(compiled, at_bolt, plan, goal["TightenBolt1"], disabled=frozenset({"human"}))


def test_no_plan_names_the_smallest_unreachable_subset() -> None:
    model = bolt_model(2)
    compiled = CompiledModel(model)
    planner = Planner(compiled)
    goals = {
        "TightenBolt1": model.operations[0].goal,
        "TightenBolt2": model.operations[1].goal,
        "RobotAway": parse_predicate("ur.pos_m == p3"),
        "Keep1": parse_predicate("engine.bolt1_e == placed"),
    }
    result = planner.plan(compiled.initial(), goals)
    assert isinstance(result, NoPlan)
    assert result.unreachable == ("TightenBolt1", "Keep1")
    # A goal unreachable on its own is named alone.
    impossible = {"TightenBolt1": goals["TightenBolt1"], "Never": parse_predicate("ur.pos_m == p3 && ur.ref_c == p0 "
                                                                                  "&& nr.fail_m && nr.tqr_m")}
    single = planner.plan(compiled.initial(), impossible)
    assert isinstance(single, NoPlan) and single.unreachable == ("Never",)


def test_unstable_start_fires_the_automatics_first() -> None:
    model = bolt_model(1)
    compiled = CompiledModel(model)
    start = compiled.with_values(compiled.initial(), {"nr.run_c": True, "nr.run_m": True, "nr.tqr_m": True,
                                                      "ur.pos_m": "p1", "ur.ref_c": "p1"})
    goal = parse_predicate("!nr.run_m")
    plan = Planner(compiled).plan(start, {"reset": goal})
    assert isinstance(plan, Plan)
    assert names(plan) == ["nr.tighten.finished", "engine.bolt1_tightened", "nr.tighten.resetting.effect"]
    baseline = breadth_first(compiled, start, goal)
    assert isinstance(baseline, Plan) and names(baseline) == names(plan)


def test_validate_plan_rejects_tampering() -> None:
    model = bolt_model(1)
    compiled = CompiledModel(model)
    goal = model.operations[0].goal
    start = compiled.initial()
    plan = Planner(compiled).plan(start, {"TightenBolt1": goal})
    assert isinstance(plan, Plan)
    validate_plan(compiled, start, plan, goal)
    dropped = Plan(plan.steps[1:], plan.states[1:], plan.goals)
    with pytest.raises(PlanInvalid) as info:
        validate_plan(compiled, start, dropped, goal)
    assert info.value.index == 0
    swapped_states = list(plan.states)
    swapped_states[2] = swapped_states[1]
    with pytest.raises(PlanInvalid, match="recorded state"):
        validate_plan(compiled, start, Plan(plan.steps, tuple(swapped_states), plan.goals), goal)
    short = Plan(plan.steps[:-1], plan.states[:-1], plan.goals)
    with pytest.raises(PlanInvalid, match="goal") as info:
        validate_plan(compiled, start, short, goal)
    assert info.value.index == len(short.steps)
    with pytest.raises(PlanInvalid, match="disabled"):
        validate_plan(compiled, start, plan, goal, disabled=frozenset({"ur"}))


def test_check_operations_reports_an_unreachable_operation() -> None:
    model = bolt_model(1)
    unreachable = operation("Impossible", "engine.bolt1_e == tightened", "engine.bolt1_e == placed")
    model = Model("bolts", model.resources, model.estimated, model.tracking, (*model.operations, unreachable))
    compiled = CompiledModel(model)
    problems = check_operations(model, compiled, Planner(compiled))
    assert len(problems) == 1
    assert "Impossible" in problems[0] and "goal" in problems[0]


def test_planner_is_reusable_across_starts_and_goals() -> None:
    model = bolt_model(3)
    compiled = CompiledModel(model)
    planner = Planner(compiled)
    goals = {op.name: op.goal for op in model.operations}
    first = planner.plan(compiled.initial(), goals)
    assert isinstance(first, Plan)
    middle = first.states[len(first.states) // 2]
    again = planner.plan(middle, goals)
    baseline = breadth_first(compiled, middle, all_of(*goals.values()))
    assert isinstance(again, Plan) and isinstance(baseline, Plan)
    assert len(again.steps) == len(baseline.steps)
    # The heuristic (projections, distance tables) is built once per goal set and reused.
    assert planner.heuristic(tuple(goals.values())) is planner.heuristic(tuple(goals.values()))


def robot_and_gripper() -> Model:
    """A gripper that grabs only while the robot is still at the pick-up place, and a robot that leaves."""
    go_c, away_m = command("r.go_c", initial=False), measured("r.away_m")
    leave = ability("r.leave", enabled=Phase(~go_c & ~away_m, deliberate="r.go_c := true"),
                    executing=Phase(go_c & ~away_m, effects="r.away_m := true"))
    lock_c, held_m = command("g.lock_c", initial=False), measured("g.held_m")
    grab = ability("g.grab", enabled=Phase(~lock_c & ~held_m, deliberate="g.lock_c := true", guard="!r.away_m"),
                   executing=Phase(lock_c & ~held_m & "!r.away_m", effects="g.held_m := true"))
    return Model("pick", (Resource("r", (go_c, away_m), (leave,)), Resource("g", (lock_c, held_m), (grab,))))


def test_a_command_never_races_an_effect_under_way() -> None:
    """Sending the robot off while the grab is due counts on the grab winning: the planner does not."""
    c = CompiledModel(robot_and_gripper())
    goal = parse_predicate("g.held_m && r.away_m")
    plan = Planner(c).plan(c.initial(), {"g": goal})
    assert isinstance(plan, Plan)
    names = [s.transition for s in plan.steps]
    assert names.index("g.grab.executing.effect") < names.index("r.leave.enabled")
    baseline = breadth_first(c, c.initial(), goal)
    assert isinstance(baseline, Plan) and len(baseline.steps) == len(plan.steps) == 4
    # Sending the robot off right after the grab command is refused by the plan check too.
    from controller.planner.validate import plan_from_moves

    moves = [(c.by_name[n].number, 0) for n in
             ("g.grab.enabled", "r.leave.enabled", "g.grab.executing.effect", "r.leave.executing.effect")]
    racy = plan_from_moves(c, c.initial(), moves, ("g",), plan.stats)
    with pytest.raises(PlanInvalid, match=r"r\.leave\.enabled starts an effect"):
        validate_plan(c, c.initial(), racy, goal)
