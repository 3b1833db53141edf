"""ControlCore's plan handling: a plan is kept while it still leads to the goals, replaced when not."""

from __future__ import annotations

from common.model import Domain, Model, Phase, Resource, ability, command, measured, operation
from common.model.compiled import CompiledModel
from controller.control import ControlCore
from controller.planner import Planner


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
    assert any(line.startswith("plan kept") for line in core.events.log)
    assert "a.switch.enabled" in core.tick().fired


def test_a_change_that_blocks_the_next_step_asks_for_a_new_plan() -> None:
    core = started_core()
    core.ingest({"g.level_m": "high"})
    core.tick()
    assert core.progress is None and core.need_plan_reason is not None and "g.level_m" in core.need_plan_reason
    assert "a.switch.enabled" not in core.tick().fired
