"""The two-stage engine: operations, then abilities; plans followed as traces; replans with reasons."""

from __future__ import annotations

from common.model import (
    Domain,
    Model,
    OperationState,
    Phase,
    Resource,
    TransitionKind,
    ability,
    all_of,
    command,
    estimated,
    measured,
    operation,
    parse_predicate,
    tracking,
)
from common.model.compiled import CompiledModel
from common.wire.ctl import ReplanReason
from controller.deorder import Execution
from controller.engine import Engine, PlanProgress
from controller.planner import Budget, Plan, Planner
from tests.test_model import nutrunner_resource


def two_lamps() -> Model:
    """Two independent devices: a command each, an effect each."""
    resources = []
    for name in ("a", "b"):
        on_c, on_m = command(f"{name}.on_c", initial=False), measured(f"{name}.on_m")
        switch = ability(f"{name}.switch", enabled=Phase(~on_c & ~on_m, deliberate=f"{name}.on_c := true"),
                         executing=Phase(on_c & ~on_m, effects=f"{name}.on_m := true"))
        resources.append(Resource(name, (on_c, on_m), (switch,)))
    return Model("lamps", tuple(resources),
                 operations=(operation("BothOn", "!a.on_m && !b.on_m", "a.on_m && b.on_m"),))


def plan_for(compiled: CompiledModel, state: tuple, goal: str) -> Plan:
    result = Planner(compiled).plan(state, {"goal": parse_predicate(goal)})
    assert isinstance(result, Plan), result
    return result


def test_nutrunner_plan_is_followed_step_by_step() -> None:
    model = Model("nr", (nutrunner_resource(),))
    c = CompiledModel(model)
    engine = Engine(c)
    start = c.initial()
    plan = plan_for(c, start, "nr.tqr_m")
    progress = PlanProgress(c, plan)
    tick = engine.tick(start, progress=progress)
    assert tick.fired == ["nr.tighten.enabled"] and tick.changed_commands == {"nr.run_c": True}
    # Nothing more fires until the device shows its effect.
    again = engine.tick(tick.state, progress=progress)
    assert again.fired == [] and again.replan is None
    running = c.with_values(again.state, {"nr.run_m": True})
    tick = engine.tick(running, progress=progress)
    assert tick.fired == [] and tick.replan is None
    done = c.with_values(tick.state, {"nr.tqr_m": True})
    tick = engine.tick(done, progress=progress)
    # The automatic transition resets run_c at once, as the paper's table says.
    assert tick.fired == ["nr.tighten.finished"] and tick.changed_commands == {"nr.run_c": False}


def test_deliberate_transitions_never_fire_without_a_plan() -> None:
    c = CompiledModel(Model("nr", (nutrunner_resource(),)))
    tick = Engine(c).tick(c.initial())
    assert tick.fired == [] and tick.changed_commands == {}


def test_a_failed_effect_leaves_the_plan_and_asks_for_a_replan() -> None:
    c = CompiledModel(Model("nr", (nutrunner_resource(),)))
    engine = Engine(c)
    plan = plan_for(c, c.initial(), "nr.tqr_m")
    progress = PlanProgress(c, plan)
    state = engine.tick(c.initial(), progress=progress).state
    state = engine.tick(c.with_values(state, {"nr.run_m": True}), progress=progress).state
    tick = engine.tick(c.with_values(state, {"nr.fail_m": True}), progress=progress)
    assert tick.replan is not None and tick.replan.reason is ReplanReason.LEFT_PLAN
    assert "nr.fail_m" in tick.replan.detail


def test_independent_steps_run_in_parallel_dependent_ones_in_order() -> None:
    model = two_lamps()
    c = CompiledModel(model)
    engine = Engine(c)
    plan = plan_for(c, c.initial(), "a.on_m && b.on_m")
    # The plan is a sequence, but both lamps are switched on in the first tick.
    tick = engine.tick(c.initial(), progress=PlanProgress(c, plan))
    assert sorted(tick.fired) == ["a.switch.enabled", "b.switch.enabled"]
    # A nutrunner cycle is one chain: its second deliberate step waits for the effects before it.
    nr = CompiledModel(Model("nr", (nutrunner_resource(),)))
    twice = plan_for(nr, nr.initial(), "nr.tqr_m")
    progress = PlanProgress(nr, twice)
    assert all(progress.depends[j] for j in range(1, len(twice.steps)))


def test_operations_start_on_request_and_finish_on_their_goal() -> None:
    c = CompiledModel(two_lamps())
    engine = Engine(c)
    tick = engine.tick(c.initial())
    assert tick.started == []  # not requested
    tick = engine.tick(c.initial(), requested=["BothOn"])
    assert tick.started == ["BothOn"] and c.unpack(tick.state)["op.BothOn"] == OperationState.EXECUTING
    lit = c.with_values(tick.state, {"a.on_m": True, "b.on_m": True, "a.on_c": True, "b.on_c": True})
    tick = engine.tick(lit, requested=["BothOn"])
    assert tick.finished == ["BothOn"] and c.unpack(tick.state)["op.BothOn"] == OperationState.FINISHED


def test_a_disabled_resource_gets_no_commands() -> None:
    c = CompiledModel(two_lamps())
    plan = plan_for(c, c.initial(), "a.on_m && b.on_m")
    tick = Engine(c).tick(c.initial(), progress=PlanProgress(c, plan), disabled=frozenset({"a"}))
    assert tick.fired == ["b.switch.enabled"] and tick.changed_commands == {"b.on_c": True}


def lamp_and_zone() -> Model:
    """A lamp whose switching reads the zone camera; the camera sees the operator, whom the controller sends."""
    on_c, on_m = command("a.on_c", initial=False), measured("a.on_m")
    switch = ability("a.switch", enabled=Phase(~on_c & ~on_m & parse_predicate("z.zone_m != robot"),
                                               deliberate="a.on_c := true"),
                     executing=Phase(on_c & ~on_m, effects="a.on_m := true"))
    go_c = command("o.go_c", initial=False)
    send = ability("o.send", enabled=Phase(~go_c, deliberate="o.go_c := true"))
    zone = measured("z.zone_m", Domain.enum("outside", "shared", "robot"), "outside")
    see = ability("z.see", executing=Phase(parse_predicate("o.go_c && z.zone_m == outside"),
                                           effects="z.zone_m := shared"))
    return Model("lz", (Resource("a", (on_c, on_m), (switch,)), Resource("o", (go_c,), (send,)),
                        Resource("z", (zone,), (see,))))


def test_an_effect_seen_before_the_steps_it_was_ordered_after_is_no_deviation() -> None:
    c = CompiledModel(lamp_and_zone())
    engine = Engine(c)
    plan = plan_for(c, c.initial(), "a.on_m && z.zone_m == shared")
    names = [s.transition for s in plan.steps]
    # The plan switches the lamp (reading the zone) before the zone changes: the zone's effect waits for it.
    assert names.index("a.switch.enabled") < names.index("z.see.executing.effect")
    progress = PlanProgress(c, plan)
    held = frozenset({"a"})  # the lamp's hub is late: the operator walks in first
    tick = engine.tick(c.initial(), progress=progress, disabled=held)
    assert tick.fired == ["o.send.enabled"]
    tick = engine.tick(c.with_values(tick.state, {"z.zone_m": "shared"}), progress=progress, disabled=held)
    assert tick.replan is None
    tick = engine.tick(tick.state, progress=progress)
    assert tick.fired == ["a.switch.enabled"] and tick.replan is None
    # A value no step of the plan writes is a deviation still.
    tick = engine.tick(c.with_values(tick.state, {"z.zone_m": "robot"}), progress=progress)
    assert tick.replan is not None and tick.replan.reason is ReplanReason.LEFT_PLAN
    assert "z.zone_m" in tick.replan.detail


def test_a_command_waits_for_the_earlier_steps_that_read_its_device() -> None:
    """The frame is recorded lifted only while the robot stands at the frame: the robot is not sent on before."""
    on_c, on_m = command("a.on_c", initial=False), measured("a.on_m")
    switch_on = ability("a.switch_on", enabled=Phase(~on_c & ~on_m, deliberate="a.on_c := true"),
                        executing=Phase(on_c & ~on_m, effects="a.on_m := true"))
    switch_off = ability("a.switch_off", enabled=Phase(on_c & on_m, deliberate="a.on_c := false"),
                         executing=Phase(~on_c & on_m, effects="a.on_m := false"))
    seen = estimated("e.seen_e", initial=False)
    record = tracking("e.record", all_of("a.on_m", "!e.seen_e"), "e.seen_e := true")
    model = Model("blink", (Resource("a", (on_c, on_m), (switch_on, switch_off)),), (seen,), (record,))
    c = CompiledModel(model)
    plan = plan_for(c, c.initial(), "e.seen_e && !a.on_m")
    names = [s.transition for s in plan.steps]
    progress = PlanProgress(c, plan)
    assert names.index("e.record") in progress.depends[names.index("a.switch_off.enabled")]


def test_an_effect_seen_before_a_record_that_needed_the_old_value_is_a_deviation() -> None:
    """As a trace: the operator is sent at once, and the camera's early effect is a deviation (the partial order
    holds the operator back: the next test)."""
    base = lamp_and_zone()
    seen = estimated("e.seen_e", initial=False)
    record = tracking("e.record", all_of("a.on_m", "z.zone_m == outside", "!e.seen_e"), "e.seen_e := true")
    c = CompiledModel(Model("lzr", base.resources, (seen,), (record,)))
    plan = plan_for(c, c.initial(), "e.seen_e && z.zone_m == shared")
    progress = PlanProgress(c, plan, execution=Execution.TRACE)
    engine = Engine(c, execution=Execution.TRACE)
    tick = engine.tick(c.initial(), progress=progress, disabled=frozenset({"a"}))
    assert tick.fired == ["o.send.enabled"]
    tick = engine.tick(c.with_values(tick.state, {"z.zone_m": "shared"}), progress=progress, disabled=frozenset({"a"}))
    assert tick.replan is not None and tick.replan.reason is ReplanReason.LEFT_PLAN
    assert "z.zone_m" in tick.replan.detail


def test_a_command_whose_effect_would_undo_a_record_waits_for_it_and_a_change_before_it_is_a_deviation() -> None:
    base = lamp_and_zone()
    seen = estimated("e.seen_e", initial=False)
    record = tracking("e.record", all_of("a.on_m", "z.zone_m == outside", "!e.seen_e"), "e.seen_e := true")
    c = CompiledModel(Model("lzr", base.resources, (seen,), (record,)))
    plan = plan_for(c, c.initial(), "e.seen_e && z.zone_m == shared")
    names = [s.transition for s in plan.steps]
    assert names.index("e.record") < names.index("z.see.executing.effect")
    progress = PlanProgress(c, plan, execution=Execution.PARTIAL_ORDER)
    engine = Engine(c, execution=Execution.PARTIAL_ORDER)
    # Sending the operator sets off the camera's effect, which takes away the zone the record needs:
    # the operator waits for the record, while the lamp's hub is late too.
    assert names.index("e.record") in progress.depends[names.index("o.send.enabled")]
    tick = engine.tick(c.initial(), progress=progress, disabled=frozenset({"a"}))
    assert tick.fired == [] and tick.replan is None
    # The operator is seen in the shared zone before the lamp is lit: the record can no longer happen.
    tick = engine.tick(c.with_values(tick.state, {"z.zone_m": "shared"}), progress=progress, disabled=frozenset({"a"}))
    assert tick.replan is not None and tick.replan.reason is ReplanReason.LEFT_PLAN
    assert "z.zone_m" in tick.replan.detail


def test_a_step_that_waited_for_a_tracking_transition_names_the_device_behind_it() -> None:
    """A tracking transition (the engine's record of a product: a filter mounted) fires the moment its guard holds,
    so a command that waited for it waited for the device step that made it hold: the idle report names that
    device, never the product ("resource engine")."""
    from controller.cycle import WaitKind
    from tests.bench.bench_planner import reference_cases

    case = next(c for c in reference_cases() if c.name.startswith("Park+"))
    planner = Planner(case.compiled, case.forbidden)
    plan = planner.plan(case.start, dict(case.goals), budget=Budget(improve_expansions=0))
    assert isinstance(plan, Plan), plan
    resources = case.compiled.model.resource_by_name
    tracked = 0
    for execution in (Execution.TRACE, Execution.PARTIAL_ORDER):
        progress = PlanProgress(case.compiled, plan, execution=execution)
        for j, t in enumerate(progress.transitions):
            if t.kind is not TransitionKind.DELIBERATE:
                continue
            progress.done_at = {d: float(d) for d in range(j)}  # every earlier step done, in plan order
            last = max(progress.depends[j], default=None)
            if last is not None:
                owner = case.compiled.paths[min(progress.transitions[last].writes)].split(".", 1)[0]
                tracked += owner not in resources
            waited = progress.waited_for(case.compiled, j, float(j))
            assert waited.kind in (WaitKind.RESOURCE, WaitKind.PLAN), waited
            assert waited.kind is WaitKind.PLAN or waited.what in resources, (t.name, waited)
    assert tracked, "no command of this plan waits for a tracking transition: the test would say nothing"
