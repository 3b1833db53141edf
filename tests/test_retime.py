"""The portfolio's member that improves plans by time (controller/retime.py), on a robot with two jobs and an operator
who needs the second of them (tests/timing_stations/two_jobs.py). Both orders of the robot's jobs are shortest plans;
only one lets the operator work beside the robot's other job, and that is the one the member and the controller take,
in process and over Zenoh."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest

from common.model import Model
from common.model.compiled import CompiledModel, State
from common.model.predicates import Predicate
from common.resources import durations_of
from controller.control import PlanRequest
from controller.cycle import predicted_finish, step_seconds
from controller.deorder import Execution, order
from controller.loop import ControlLoop
from controller.planner import Plan, Planner
from controller.planner.plans import PlanStep
from controller.planner.policy import VIRTUAL_BUDGET
from controller.planworker import Limits, PlannerProcess, Timing
from controller.recording.hooks import RunRecorder, VirtualClock
from controller.retime import Retimer, retime
from controller.stack import build_controller_stack
from deploy.local.inprocess import run_in_process
from tests.test_causal_chain import fastest_schedule
from tests.timing_stations import up
from tests.timing_stations.two_jobs import OPERATOR_S, ROBOT_S, build_model, goal

ROOT = Path(__file__).resolve().parent.parent
TWO_JOBS = ROOT / "tests" / "timing_stations" / "two_jobs.toml"
WARM_UP = "tests.timing_stations.two_jobs:with_warm_up"
GOAL = goal()
A_FIRST = ("r.do_a.enabled", "r.do_a.executing.effect", "r.do_a.done", "r.do_b.enabled", "r.do_b.executing.effect",
           "r.do_b.done", "o.work.enabled", "o.work.executing.effect")


def seconds(model: Model) -> dict[str, float]:
    return {t.name: ROBOT_S if t.name.startswith("r.") else OPERATOR_S
            for t in model.ability_transitions if t.kind.value == "effect"}


def job_a_first(model: Model) -> tuple[CompiledModel, Planner, dict[str, Predicate], Plan]:
    """The station's compiled model and planner, its goals, and the plan that does job a first."""
    stack = build_controller_stack(model)
    compiled, planner = stack.compiled, stack.planner
    goals = {"Work": compiled.model.operation_by_name["Work"].goal}
    start = compiled.initial()
    slow = planner.revalidate(start, _steps(planner, start, A_FIRST, goals), goals)
    assert slow is not None
    return compiled, planner, goals, slow


def test_the_robots_jobs_are_swapped_so_that_the_operator_works_beside_the_other() -> None:
    model = build_model()
    compiled, planner, goals, slow = job_a_first(model)
    durations = seconds(model)
    assert _finish(compiled, slow, durations) == 2 * ROBOT_S + OPERATOR_S  # the operator waits for both jobs

    found = retime(compiled, slow, durations, Execution.PARTIAL_ORDER,
                   lambda state, steps: planner.revalidate(state, steps, goals))
    assert found is not None
    assert (found.before_s, found.after_s) == (11.0, 8.0)
    assert [s.transition for s in found.plan.steps][:3] == ["r.do_b.enabled", "r.do_b.executing.effect",
                                                          "r.do_b.done"]
    assert len(found.plan.steps) == len(slow.steps) and found.plan.goals == slow.goals
    assert "retimed" in found.plan.stats.method
    assert _finish(compiled, found.plan, durations) == fastest_schedule(compiled, GOAL, durations) == 8.0

    # in a strict sequence the order changes nothing, and a plan already fastest is left alone
    assert retime(compiled, slow, durations, Execution.SEQUENCE,
                  lambda state, steps: planner.revalidate(state, steps, goals)) is None
    assert retime(compiled, found.plan, durations, Execution.PARTIAL_ORDER,
                  lambda state, steps: planner.revalidate(state, steps, goals)) is None


def test_every_order_the_member_tries_is_checked_by_the_planner() -> None:
    """With the planner's check refusing every new order, nothing comes back: the member never hands out a
    sequence the engine's semantics have not accepted."""
    model = build_model()
    compiled, planner, goals, slow = job_a_first(model)
    start = slow.states[0]
    checked: list[tuple[str, ...]] = []

    def refuse(_state: State, steps: Sequence[PlanStep]) -> Plan | None:
        checked.append(tuple(s.transition for s in steps))
        return None

    assert retime(compiled, slow, seconds(model), Execution.PARTIAL_ORDER, refuse) is None
    assert checked and all(sorted(c) == sorted(A_FIRST) for c in checked)
    request = PlanRequest(1, start, goals, frozenset())
    assert Retimer(planner, seconds(model), Execution.PARTIAL_ORDER).faster(slow, request, tries=0) is None


def test_the_controller_runs_the_faster_order_and_ends_at_the_fastest_schedule() -> None:
    model = build_model()
    compiled = build_controller_stack(model).compiled
    fastest = fastest_schedule(compiled, GOAL, seconds(model))
    with_member = run_in_process(model, seed=1)
    without = run_in_process(model, seed=1, budget=dataclasses.replace(VIRTUAL_BUDGET, retime_tries=0))
    assert with_member.finished and without.finished, (with_member.reason, without.reason)
    assert with_member.cycle is not None and without.cycle is not None
    assert with_member.cycle.cycle <= fastest + 0.5  # the engine's tick and dispatch, no more
    # the planner's own choice is the slower order here; the member is what makes the difference
    assert without.cycle.cycle >= 2 * ROBOT_S + OPERATOR_S


def _steps(planner: Planner, start: State, names: tuple[str, ...], goals: dict[str, Predicate]) -> list[PlanStep]:
    """The plan steps of `names`, in that order, as the planner prints them (its own plan has the same steps)."""
    plan = planner.plan(start, goals, frozenset(), budget=VIRTUAL_BUDGET)
    assert isinstance(plan, Plan)
    by_name = {step.transition: step for step in plan.steps}
    return [by_name[name] for name in names]


def _finish(compiled: CompiledModel, plan: Plan, durations: dict[str, float]) -> float:
    return predicted_finish(order(compiled, plan, Execution.PARTIAL_ORDER), step_seconds(compiled, plan, durations))


@pytest.mark.timeout(180)
async def test_over_zenoh_the_first_plan_goes_out_in_the_faster_order(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """Hubs and controller as processes: the planner process's first plan does job a first, and a short look by the
    member before it goes out finds job b first faster; the robot does b first, the operator beside a."""
    lines = await up(TWO_JOBS, tmp_path, monkeypatch, 60.0)
    output = "\n".join(lines)
    started = [line.split("r: ", 1)[1].split()[0] for line in lines if " now " in line and "r: " in line]
    assert started.index("do_b") < started.index("do_a"), output


@pytest.mark.timeout(180)
async def test_the_planner_process_sends_the_faster_order_after_its_first_plan_and_the_loop_takes_it() -> None:
    """With no time to improve the first plan, it goes out as the planner found it (job a first); after the
    portfolio the process sends the same steps with job b first, checked in time, and the control loop that runs
    the first plan takes them: no shorter, predicted faster, valid from where the station is."""
    model = build_model(warm_up=True, robot_s=1.0, operator_s=1.6)
    timing = Timing({e.resource: e.duration for e in durations_of(model).entries}, Execution.PARTIAL_ORDER)
    process = PlannerProcess(WARM_UP, Limits(first_seconds=10.0, improve_seconds=5.0, hold_seconds=0.0,
                                             first_retime_seconds=0.0), timing=timing)
    stack = build_controller_stack(model)
    clock = VirtualClock()
    core = stack.control_core(clock, execution=Execution.PARTIAL_ORDER)
    loop = ControlLoop(core, RunRecorder(core, clock, None), (r.name for r in model.resources), clock,
                       seconds={t.name: 1.0 if t.name.startswith("r.") else 1.6
                                for t in model.ability_transitions if t.kind.value == "effect"})
    loop.request(["Work"])
    loop.tick()
    request = loop.plan_request()
    assert request is not None
    try:
        assert await process.ready(60.0)
        answers = [a async for a in process.answers(request)]
    finally:
        process.close()
    plans = [a.result for a in answers if isinstance(a.result, Plan)]
    first, last = plans[0], plans[-1]
    assert [s.transition for s in first.steps][3] == "r.do_a.enabled"
    assert [s.transition for s in last.steps][3] == "r.do_b.enabled" and "retimed" in last.stats.method
    assert sorted(s.transition for s in last.steps) == sorted(s.transition for s in first.steps)
    taken = []
    for answer in answers:  # as the controller's plan client hands them to the loop
        if answer.verdict is not None:
            loop.checked(request, answer.verdict)  # the first plan runs in the engine's order from now on
        elif answer.result is first:
            assert loop.adopt(request, first).taken
        elif isinstance(answer.result, Plan):
            cursor = core.events.log.total
            if loop.improve(request, answer.result):
                taken += [type(e).__name__ for e in core.events.log.since(cursor).events]
    assert taken == ["FasterPlan"]
    assert core.progress is not None and core.progress.plan.steps == last.steps


def test_the_controller_takes_a_plan_no_shorter_only_when_it_is_predicted_faster() -> None:
    """`ControlCore.improve`: the rest of a plan under way replaced by as many steps in another order only with a
    finish estimate that says it ends sooner (by 1 % at least), and only from the state the station is in."""
    stack = build_controller_stack(build_model())
    core = stack.control_core(budget=dataclasses.replace(VIRTUAL_BUDGET, retime_tries=0))
    core.request("Work")
    core.tick()
    request = core.plan_request()
    assert request is not None
    planner, compiled = stack.planner, stack.compiled
    slow = planner.revalidate(request.start, _steps(planner, request.start, A_FIRST, request.goals), request.goals)
    assert slow is not None
    core.adopt(request, slow)
    found = Retimer(planner, seconds(build_model()), core.engine.execution).faster(slow, request)
    assert found is not None
    fast = found.plan

    def predicted(plan: Plan, done: frozenset[int]) -> float:
        durations = step_seconds(compiled, plan, seconds(build_model()))
        return predicted_finish(order(compiled, plan, core.engine.execution),
                                [0.0 if j in done else d for j, d in enumerate(durations)])

    assert not core.improve(request, fast)  # no shorter, and no estimate to tell it faster
    assert not core.improve(request, fast, lambda plan, done: 1.0)  # as fast as what is left
    stale = PlanRequest(request.generation - 1, request.start, request.goals, request.disabled)
    assert not core.improve(stale, fast, predicted)
    elsewhere = dataclasses.replace(fast, steps=fast.steps[3:], states=fast.states[3:])  # from job b done
    assert not core.improve(request, elsewhere, predicted)
    cursor = core.events.log.total
    assert core.improve(request, fast, predicted)
    assert core.progress is not None and core.progress.plan.steps == fast.steps
    taken = core.events.log.since(cursor).events
    assert [type(e).__name__ for e in taken] == ["FasterPlan"]
    assert (taken[0].steps, taken[0].seconds, taken[0].instead_of) == (8, 8.0, 11.0)  # type: ignore[union-attr]


def test_what_the_member_found_for_a_plan_is_remembered_unless_its_search_was_cut_short(
        monkeypatch: pytest.MonkeyPatch) -> None:
    model = build_model()
    _compiled, planner, goals, slow = job_a_first(model)
    request = PlanRequest(1, slow.states[0], goals, frozenset())
    checks: list[int] = []
    revalidate = planner.revalidate

    def counted(*args: Any, **kwargs: Any) -> Plan | None:
        checks.append(1)
        return revalidate(*args, **kwargs)

    monkeypatch.setattr(planner, "revalidate", counted)
    retimer = Retimer(planner, seconds(model), Execution.PARTIAL_ORDER)
    assert retimer.faster(slow, request, stop=lambda: True) is None and not checks  # stopped before any order
    found = retimer.faster(slow, request)
    assert found is not None and checks
    checked = len(checks)
    assert retimer.faster(slow, request) == found and len(checks) == checked  # remembered: nothing checked again


def test_hubctl_plan_shows_the_order_the_controller_sends_out(capsys: pytest.CaptureFixture[str],
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """`hubctl plan` prints the planner's plan, then the faster order the member finds in the engine's order at the
    station's durations (job b first, the operator working beside a); on a plan already fastest it says so."""
    from deploy.cli import main as hubctl

    monkeypatch.chdir(ROOT)
    config = ROOT / "tests" / "timing_stations" / "two_jobs.toml"
    assert hubctl(["plan", "--config", str(config), "Work"]) == 0
    out = capsys.readouterr().out
    faster = out.index("the controller takes these steps in a faster order")
    # two_jobs.toml's delays: the robot's jobs 1 s each, the operator's work 1.6 s
    assert "predicted to end at 2.60 s instead of 3.60 s in the engine's trace order" in out, out
    planned, sent = out[:faster], out[faster:]
    assert planned.index("r.do_a.enabled") < planned.index("r.do_b.enabled"), planned
    assert sent.index("r.do_b.enabled") < sent.index("r.do_a.enabled"), sent
    assert hubctl(["plan", "--model", "tests.stations.timing:feeder_station", "Place"]) == 0
    assert "no faster order of these steps in the engine's trace order" in capsys.readouterr().out
