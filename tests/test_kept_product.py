"""What is done to the product stays done (controller/kept_product.py): a plan for the executing operations
does not undo a finished operation's product goal, and a goal that cannot be kept does not stall the station."""

from __future__ import annotations

import logging

import pytest

from common.model import (
    Domain,
    Model,
    OperationState,
    Phase,
    Resource,
    ability,
    command,
    estimated,
    measured,
    operation,
    tracking,
)
from common.model.compiled import CompiledModel
from controller.control import ControlCore
from controller.planner import Plan, Planner

PIPE = Domain.enum("absent", "mounted", "tightened")


def switch(name: str, after: str | None = None) -> tuple[Resource, ...]:
    """`name.on_m` in two steps (command, then its effect); with `after`, that switch has to be on first."""
    on_c, on_m = command(f"{name}.on_c", initial=False), measured(f"{name}.on_m")
    enabled = f"!{name}.on_c && !{name}.on_m" + (f" && {after}.on_m" if after else "")
    flip = ability(f"{name}.switch", enabled=Phase(enabled, deliberate=f"{name}.on_c := true"),
                   executing=Phase(f"{name}.on_c && !{name}.on_m", effects=f"{name}.on_m := true"))
    return (Resource(name, (on_c, on_m), (flip,)),)


def tool_station(*, slow_route: bool = True, product: tuple[str, ...] = ("w.*",)) -> Model:
    """The tool can be had two ways: switch `x` (two steps), whose command knocks the finished pipe back to
    `mounted`, or, with `slow_route`, switch `y` after switch `z` (four steps) that leaves the pipe alone.
    Nothing tightens the pipe again. The shortest plan for `Tool` undoes `Tighten`."""
    resources = (*switch("x"), *switch("z"), *switch("y", after="z"))
    spoiled = tracking("w.spoiled", "w.pipe_e == tightened && x.on_c", "w.pipe_e := mounted")
    tool = "x.on_m || y.on_m" if slow_route else "x.on_m"
    return Model("tool_station", resources, (estimated("w.pipe_e", PIPE, "absent"),), (spoiled,),
                 (operation("Tighten", "w.pipe_e == mounted", "w.pipe_e == tightened"),
                  operation("Tool", "true", tool)), product=product)


def tool_requested(model: Model) -> tuple[ControlCore, CompiledModel]:
    compiled = CompiledModel(model)
    core = ControlCore(compiled, Planner(compiled))
    core.state = compiled.with_values(core.state, {"w.pipe_e": "tightened",
                                                   "op.Tighten": OperationState.FINISHED.value})
    core.request("Tighten", "Tool")  # as an order requests its operations: all of them, finished ones included
    core.tick()
    return core, compiled


def planned(core: ControlCore) -> Plan:
    request = core.plan_request()
    assert request is not None
    result = core.solve(request)
    assert isinstance(result, Plan), result
    return result


def test_the_plan_leaves_a_finished_operations_product_goal_holding() -> None:
    core, compiled = tool_requested(tool_station())
    request = core.plan_request()
    assert request is not None and set(request.goals) == {"Tool"} and set(request.keep) == {"Tighten"}
    plan = core.solve(request)
    assert isinstance(plan, Plan) and plan.goals == ("Tool",)  # the plan names the request's goals only
    assert not any(step.transition.startswith("x.") for step in plan.steps), plan.explain(compiled)
    assert compiled.unpack(plan.states[-1])["w.pipe_e"] == "tightened"


def test_without_the_kept_goal_the_shortest_plan_undoes_the_finished_work() -> None:
    """The same request with nothing kept (a station that declares no product): the two-step route through
    `x`, which knocks the pipe back. This is what the kept goal prevents, so the test above can fail."""
    core, compiled = tool_requested(tool_station(product=()))
    request = core.plan_request()
    assert request is not None and request.keep == {}
    plan = core.solve(request)
    assert isinstance(plan, Plan) and plan.steps[0].transition.startswith("x.")
    assert compiled.unpack(plan.states[-1])["w.pipe_e"] == "mounted"


def test_a_goal_that_cannot_be_kept_is_planned_without_keeping_it(caplog: pytest.LogCaptureFixture) -> None:
    """Only the route that undoes the finished work reaches the goal: the station goes on, and says so."""
    core, compiled = tool_requested(tool_station(slow_route=False))
    with caplog.at_level(logging.WARNING, logger="statehub.controller.planner"):
        plan = planned(core)
    assert plan.goals == ("Tool",) and compiled.unpack(plan.states[-1])["x.on_m"] is True
    assert "keeps Tighten as finished" in caplog.text and "planning without keeping them" in caplog.text


def test_a_finished_goal_is_not_kept_while_an_operation_still_to_run_moves_its_variables() -> None:
    model = tool_station()
    compiled = CompiledModel(model)
    core = ControlCore(compiled, Planner(compiled))
    finished = compiled.with_values(core.state, {"w.pipe_e": "tightened", "op.Tighten": OperationState.FINISHED.value})
    tighten = {"Tighten": model.operation_by_name["Tighten"].goal}
    assert core.kept_product.goals(finished, ["Tool"]) == tighten
    # An operation requested and finished moves nothing more; one still to run moves the pipe itself.
    assert core.kept_product.goals(finished, ["Tool", "Tighten"]) == tighten
    to_run_again = compiled.with_values(finished, {"op.Tighten": OperationState.EXECUTING.value})
    assert core.kept_product.goals(to_run_again, ["Tool", "Tighten"]) == {}
    undone = compiled.with_values(finished, {"w.pipe_e": "mounted"})
    assert core.kept_product.goals(undone, ["Tool"]) == {}  # what no longer holds is not put back
    not_finished = compiled.with_values(finished, {"op.Tighten": OperationState.INITIAL.value})
    assert core.kept_product.goals(not_finished, ["Tool"]) == {}
