"""ControlCore's plan handling: a plan is kept while it still leads to the goals, replaced when not."""

from __future__ import annotations

from common.model import Domain, Model, OperationState, Phase, Resource, ability, command, measured, operation
from common.model.compiled import CompiledModel
from common.wire.ctl import NoPlanFound, PlanFound, PlanKept, ReplanReason
from controller.control import ControlCore, PlanRequest
from controller.planner import NoPlan, Plan, Planner


def lamp_beside_a_gauge() -> Model:
    """A lamp that may be switched unless the gauge reads high; nothing the controller does moves the gauge."""
    on_c, on_m = command("a.on_c", initial=False), measured("a.on_m")
    switch = ability("a.switch", enabled=Phase(~on_c & ~on_m & "g.level_m != high", deliberate="a.on_c := true"),
                     executing=Phase(on_c & ~on_m, effects="a.on_m := true"))
    level = measured("g.level_m", Domain.enum("low", "mid", "high"), "low")
    return Model("lamp", (Resource("a", (on_c, on_m), (switch,)), Resource("g", (level,), ())),
                 operations=(operation("LampOn", "!a.on_m", "a.on_m"),))


def started_core() -> ControlCore:
    compiled = CompiledModel(lamp_beside_a_gauge())
    core = ControlCore(compiled, Planner(compiled))
    core.request("LampOn")
    core.tick()
    request = core.plan_request()
    assert request is not None
    core.adopt(request, core.solve(request))
    assert core.progress is not None
    return core


def test_a_change_no_step_waits_for_keeps_the_plan() -> None:
    core = started_core()
    core.ingest({"g.level_m": "mid"})  # the plan predicted "low"; its steps still fire at "mid"
    core.tick()
    assert core.need_plan_reason is None and core.progress is not None
    kept = [event for event in core.events.log if isinstance(event, PlanKept)]
    assert len(kept) == 1 and kept[0].cause.reason is ReplanReason.LEFT_PLAN and "g.level_m" in kept[0].cause.detail
    assert "a.switch.enabled" in core.tick().fired


def test_a_change_that_blocks_the_next_step_asks_for_a_new_plan() -> None:
    core = started_core()
    core.ingest({"g.level_m": "high"})
    core.tick()
    why = core.need_plan_reason
    assert core.progress is None and why is not None
    assert why.reason is ReplanReason.LEFT_PLAN and "g.level_m" in why.detail
    assert "a.switch.enabled" not in core.tick().fired


def test_a_goal_without_a_plan_goes_to_error_once_and_is_retried_with_backoff() -> None:
    compiled = CompiledModel(lamp_beside_a_gauge())
    now = [0.0]
    core = ControlCore(compiled, Planner(compiled), clock=lambda: now[0])
    core.request("LampOn")
    core.ingest({"g.level_m": "high"})  # the switch is forbidden for as long as the gauge reads high
    core.tick()
    waits = []
    for _ in range(4):
        request = core.plan_request()
        assert request is not None and set(request.goals) == {"LampOn"}
        result = core.solve(request)
        assert isinstance(result, NoPlan) and result.proven
        core.adopt(request, result)
        assert core.op_state("LampOn") == OperationState.ERROR
        error = core.errors["LampOn"]
        waits.append(error.retry_at - now[0])
        empty = core.plan_request()  # planned again without the goal, until its retry is due
        assert empty is not None and not empty.goals
        core.adopt(empty, core.solve(empty))
        core.tick()
        assert core.plan_request() is None
        now[0] = error.retry_at
        core.tick()
    assert waits == [2.0, 4.0, 8.0, 16.0]
    said = [event for event in core.events.log if isinstance(event, NoPlanFound)]
    assert len(said) == 1 and said[0].proven and said[0].operations == ["LampOn"]
    assert said[0].text.startswith("no plan (unreachable) for LampOn: ")
    assert "attempt 4" in core.error_text("LampOn")
    core.ingest({"g.level_m": "low"})
    core.tick()
    request = core.plan_request()
    assert request is not None
    core.adopt(request, core.solve(request))
    assert core.op_state("LampOn") == OperationState.EXECUTING and "LampOn" not in core.errors
    assert PlanFound("LampOn", 4) in core.events.log


def test_a_shorter_plan_is_taken_only_while_valid_from_the_measured_state() -> None:
    core = started_core()
    assert core.progress is not None
    plan = core.progress.plan
    request = PlanRequest(core.generation, plan.states[0], {"LampOn": lamp_beside_a_gauge().operation_by_name[
        "LampOn"].goal}, frozenset())
    # Not shorter than what is left: refused.
    assert not core.improve(request, plan)
    # A "better" plan from a state the station is not in: refused.
    elsewhere = Plan(plan.steps[1:], plan.states[1:], plan.goals, plan.stats)
    assert not core.improve(request, elsewhere) or core.state == plan.states[1]
    # An answer to an older request: refused.
    stale = PlanRequest(core.generation - 1, request.start, request.goals, frozenset())
    assert not core.improve(stale, plan)
