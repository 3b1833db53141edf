"""Plans checked in time before use (issue 21, item 2: controller/timed_check.py).

A plan that counts on an enabled effect waiting for it is refused, naming the effect and the step; the controller
then runs it in a stricter order, or teaches the planner the race and plans again. Stations that got stuck
before: the timed random stations with a specification guarding their feeder's sensor (`WITH_GUARDED`), and the
reference station with a slow operator in partial order.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from common.model import Duration, all_of
from common.resources import durations_of
from common.stations import load_model
from controller.deorder import Execution
from controller.planner import Plan
from controller.planner.plans import PlanStats
from controller.planner.policy import VIRTUAL_BUDGET
from controller.stack import ControllerStack, build_controller_stack
from controller.timed_check import TimedCheck, TimingFault, TimingRefusal, corner_timings
from deploy.local.inprocess import run_in_process
from deploy.local.statefile import load_state
from tests.stations.random_timed_station import WITH_GUARDED, build_random_timed_station_with_shape
from tests.timing_stations.feeder import build_model as build_feeder_station

# The seeds whose stations got stuck in trace and in partial order before plans were checked in time.
GUARDED_SEEDS = (25, 30, 60, 68, 157, 158, 167, 336)


def _first_plan(seed: int) -> tuple[TimedCheck, Plan, ControllerStack]:
    model, _ = build_random_timed_station_with_shape(seed, timings=WITH_GUARDED)
    stack = build_controller_stack(model)
    durations = {e.resource: e.duration for e in durations_of(model).entries}
    goals = {op.name: op.goal for op in model.operations}
    plan = stack.planner.plan(stack.compiled.initial(), goals, budget=VIRTUAL_BUDGET)  # as in process
    assert isinstance(plan, Plan)
    return TimedCheck(stack.compiled, durations), plan, stack


def test_a_plan_counting_on_an_effect_waiting_is_refused_naming_the_effect_and_the_step() -> None:
    check, plan, _ = _first_plan(60)
    refused = check.refusal(plan)
    assert refused is not None
    # The plan switches the vacuum off before the feeder's sensor has seen the box taken: the release comes first.
    assert refused.fault is TimingFault.LEFT_PLAN
    assert refused.effect == "g1.release.executing.effect"
    assert refused.transition == "f1.taken.executing.effect"
    assert plan.steps[refused.step].transition == refused.transition
    assert refused.effect in refused.text and refused.transition in refused.text


def test_the_race_forbidden_the_planner_finds_a_plan_no_timing_breaks() -> None:
    check, plan, stack = _first_plan(60)
    refused = check.refusal(plan)
    assert refused is not None
    planner, compiled = stack.planner, stack.compiled
    assert planner.timed_races.forbid(compiled.by_name[refused.transition], compiled.by_name[refused.effect])
    goals = {op.name: op.goal for op in compiled.model.operations}
    again = planner.plan(compiled.initial(), goals, budget=VIRTUAL_BUDGET)
    assert isinstance(again, Plan)
    assert check.refusal(again) is None


def test_a_plan_the_devices_follow_is_not_refused_and_fixed_durations_give_one_timing() -> None:
    model = build_feeder_station()
    stack = build_controller_stack(model)
    durations = {e.resource: Duration.fixed(e.duration.max_s) for e in durations_of(model).entries}
    assert len(corner_timings(stack.compiled, durations)) == 1
    check = TimedCheck(stack.compiled, durations)
    plan = stack.planner.plan(stack.compiled.initial(), {op.name: op.goal for op in model.operations})
    assert isinstance(plan, Plan)
    assert check.refusal(plan) is None


def test_an_interval_is_checked_at_both_ends_for_each_resource() -> None:
    model, _ = build_random_timed_station_with_shape(60, timings=WITH_GUARDED)
    stack = build_controller_stack(model)
    durations = {e.resource: e.duration for e in durations_of(model).entries}
    owners = {t.name: t.name.split(".", 1)[0] for t in stack.compiled.effects}
    varying = sorted({r for r in owners.values() if not durations[r].is_fixed})
    assert len(varying) >= 2
    ends = [{r: {s for name, s in t.seconds.items() if owners[name] == r} for r in varying}
            for t in corner_timings(stack.compiled, durations)]
    for r in varying:
        for other in varying:
            if other != r:  # r early while `other` is late, and the other way round
                assert any(e[r] == {durations[r].min_s} and e[other] == {durations[other].max_s} for e in ends)
                assert any(e[r] == {durations[r].max_s} and e[other] == {durations[other].min_s} for e in ends)


@pytest.mark.parametrize("execution", [Execution.TRACE, Execution.PARTIAL_ORDER])
@pytest.mark.parametrize("seed", GUARDED_SEEDS)
def test_guarded_timed_stations_complete(seed: int, execution: Execution) -> None:
    model, shape = build_random_timed_station_with_shape(seed, timings=WITH_GUARDED)
    summary = run_in_process(model, seed=seed, time_limit=300.0, execution=execution)
    assert summary.finished, (shape.describe(), summary.reason, summary.log[-8:])


@pytest.mark.slow
def test_reference_station_with_a_slow_operator_completes_in_partial_order() -> None:
    # Before: stuck at TightenPipe2, the shortest plan recording pipe 2 on pipe 1's torque (livelock after 20 plans).
    summary = run_in_process(load_model(), seed=1, delays={"human": 30.0}, execution=Execution.PARTIAL_ORDER,
                             time_limit=900.0)
    assert summary.finished, (summary.reason, summary.log[-8:])


PIPE2_STATE = Path(__file__).resolve().parent / "timing_stations" / "pipe2_after_pipe1_confirmed.toml"


def test_of_two_effects_at_once_the_one_that_broke_the_plan_is_blamed() -> None:
    """The recorded state above: the plan's refusal names the dock taking the nutrunner back (it wrote the value
    the plan did not expect), not the camera that saw the operator step out at the same moment. Learnt against
    the camera, the race sent the planner round through the instruction for pipe 1 again and again (a chaos run
    livelocked so); against the dock, the next plan waits for the nutrunner."""
    model = load_model("common.stations.engine_assembly:build_model")
    stack = build_controller_stack(model)
    compiled = stack.compiled
    start = compiled.pack({**model.initial_state(), **load_state(PIPE2_STATE, model)})
    goals = {name: model.operation_by_name[name].goal for name in ("TightenPipe2", "RobotHome")}
    plan = stack.planner.plan(start, goals, budget=VIRTUAL_BUDGET)
    assert isinstance(plan, Plan)
    durations = {e.resource: e.duration for e in durations_of(model).entries}
    refused = TimedCheck(compiled, durations).refusal(plan)
    assert refused is not None and refused.effect == "dock.nutrunner_returns.executing.effect", refused
    assert "dock.nutrunner_home_m" in refused.text


def test_the_symbolic_member_keeps_to_the_races_learnt() -> None:
    """A race learnt is kept by every member: the symbolic one builds its moves ahead of time, so it is built again
    with the race in. Before, its shortest plan instructed pipe 2 while the dock was taking the nutrunner back, failed
    the planner's own check, and the request had no plan ("internal error")."""
    model = load_model("common.stations.engine_assembly:build_model")
    stack = build_controller_stack(model)
    compiled, planner = stack.compiled, stack.planner
    start = compiled.pack({**model.initial_state(), **load_state(PIPE2_STATE, model)})
    goal = all_of(*(model.operation_by_name[name].goal for name in ("TightenPipe2", "RobotHome")))
    returns = compiled.by_name["dock.nutrunner_returns.executing.effect"]
    assert planner.timed_races.forbid(compiled.by_name["human.tighten_pipe2.enabled"], returns)
    symbolic = planner.symbolic(frozenset())
    assert symbolic is not None
    found = symbolic.search(start, goal)
    assert found.moves is not None
    plan = planner.checked_plan(start, found.moves, ("TightenPipe2", "RobotHome"), PlanStats("symbolic"),
                                planner.goal_test(goal), frozenset())  # PlanInvalid for a plan that loses the race
    instructed = next(j for j, step in enumerate(plan.steps) if step.transition == "human.tighten_pipe2.enabled")
    assert not returns.guard(plan.states[instructed])


def test_the_satisficing_member_takes_the_effect_a_learnt_race_waits_for() -> None:
    """With the race learnt (pipe 2 not instructed while the dock takes the nutrunner back), the plan has to take
    the dock's effect first. No relaxed plan holds it (it matters to no goal), so the greedy search never preferred
    it and ran out of its 20,000 states; the effects a preferred move waits for are preferred now."""
    model = load_model("common.stations.engine_assembly:build_model")
    stack = build_controller_stack(model)
    compiled, planner = stack.compiled, stack.planner
    start = compiled.pack({**model.initial_state(), **load_state(PIPE2_STATE, model)})
    for victim, due in (("human.tighten_pipe2.enabled", "cam.sees_robot.executing.effect"),
                        ("human.tighten_pipe2.enabled", "nr.tighten.resetting.effect"),
                        ("human.tighten_pipe2.enabled", "dock.nutrunner_returns.executing.effect")):
        assert planner.timed_races.forbid(compiled.by_name[victim], compiled.by_name[due])
    goals = {name: model.operation_by_name[name].goal for name in ("TightenPipe2", "RobotHome")}
    plan = planner.plan(start, goals, budget=VIRTUAL_BUDGET)
    assert isinstance(plan, Plan) and plan.stats.method == "greedy", plan.stats
    steps = [step.transition for step in plan.steps]
    assert steps.index("dock.nutrunner_returns.executing.effect") < steps.index("human.tighten_pipe2.enabled")


def test_a_verdict_is_remembered_for_the_same_plan_and_races_and_checked_again_once_a_race_is_learnt(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """In production the same plans come back from the same states order after order: the check's answer is
    remembered, for the planner's revalidation only while the races it learnt are the same, never for a
    revalidation it cannot tell apart, and never for a check `stop` cut short."""
    from controller.timed_check import CheckStopped, revalidation

    check, plan, stack = _first_plan(60)
    simulated: list[str] = []
    run = check._run

    def counting(*args: Any) -> TimingRefusal | None:
        simulated.append("run")
        return run(*args)

    monkeypatch.setattr(check, "_run", counting)  # counts the simulations the check runs
    goals = {op.name: op.goal for op in stack.compiled.model.operations}
    keep = revalidation(stack.planner, goals, plan, frozenset())
    assert keep is not None
    first = check.refusal(plan, revalidate=keep)
    runs = len(simulated)
    assert first is not None and runs >= 1
    assert check.refusal(plan, revalidate=revalidation(stack.planner, goals, plan, frozenset())) is first
    assert len(simulated) == runs  # remembered
    assert check.refusal(plan, execution=Execution.SEQUENCE, revalidate=keep) is not first
    runs = len(simulated)
    assert check.refusal(plan, revalidate=lambda state, steps: keep(state, steps)) == first
    assert len(simulated) > runs  # a revalidation of unknown behaviour: simulated again
    runs = len(simulated)
    compiled = stack.compiled
    assert stack.planner.timed_races.forbid(compiled.by_name[first.transition], compiled.by_name[first.effect])
    check.refusal(plan, revalidate=keep)
    assert len(simulated) > runs  # a race learnt: the revalidation may answer otherwise
    with pytest.raises(CheckStopped):
        check.refusal(plan, frozenset({"nobody"}), stop=lambda: True)
    runs = len(simulated)
    check.refusal(plan, frozenset({"nobody"}))
    assert len(simulated) > runs  # the stopped check was not remembered
    unremembering = TimedCheck(compiled, check_durations(stack), kept=0)
    assert unremembering.refusal(plan, revalidate=keep) == check.refusal(plan, revalidate=keep)


def check_durations(stack: ControllerStack) -> dict[str, Duration]:
    return {e.resource: e.duration for e in durations_of(stack.compiled.model).entries}
