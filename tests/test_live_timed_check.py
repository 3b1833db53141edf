"""The live controller checks its plans in time in its planner process (controller/planworker.py): the first
plan goes out at once to run step after step, its verdict follows; a race the plan loses in every order is
learnt there, and the next plan wins it. The controller's side takes the verdict (`ControlLoop.checked`)."""

from __future__ import annotations

import asyncio
import dataclasses
from pathlib import Path

import pytest

from common.config.hubs_toml import load_config
from common.config.modes import DEFAULT_EXECUTION
from common.model import Model, OperationState
from common.resources import durations_of
from controller.control import PlanRequest
from controller.deorder import Execution
from controller.loop import ControlLoop
from controller.planner import Plan
from controller.planworker import Answer, Limits, PlannerProcess, Timing
from controller.recording.hooks import RunRecorder, VirtualClock
from controller.recording.reader import open_run
from controller.stack import build_controller_stack
from controller.timed_check import STRICTEST, CheckStopped, TimedCheck, Verdict
from deploy.replay.replay import Replayer
from tests.stations.random_timed_station import WITH_GUARDED, build_random_timed_station_with_shape
from tests.timing_stations import up
from tests.timing_stations.feeder import build_model

FEEDER = "tests.timing_stations.feeder:build_model"
CONFIG = Path(__file__).parent / "timing_stations" / "hubs.toml"
ROOT = Path(__file__).resolve().parent.parent
GUARDED = "tests.test_live_timed_check:guarded_station"
GUARDED_SEED = 60  # its first plan switches the vacuum off before the feeder's sensor saw the box taken

pytestmark = pytest.mark.timeout(180)


def guarded_station() -> Model:
    """A random timed station with a specification guarding its feeder's sensor (tests/test_timed_check.py)."""
    return build_random_timed_station_with_shape(GUARDED_SEED, timings=WITH_GUARDED)[0]


def station_timing(model: Model, config: Path | None = None) -> Timing:
    """What the controller service gives its planner process: the model's durations under hubs.toml's."""
    table = durations_of(model, None if config is None else load_config(config, model=model).delays)
    return Timing({e.resource: e.duration for e in table.entries})


def every_operation(model: Model, generation: int) -> PlanRequest:
    compiled = build_controller_stack(model).compiled
    values = model.initial_state()
    for op in model.operations:
        values[op.state_path] = OperationState.EXECUTING.value
    return PlanRequest(generation, compiled.pack(values), {op.name: op.goal for op in model.operations},
                       frozenset())


async def collect(process: PlannerProcess, request: PlanRequest) -> list[Answer]:
    return [answer async for answer in process.answers(request)]


NO_IMPROVEMENT = Limits(first_seconds=10.0, improve_seconds=0.0, hold_seconds=0.0)  # what is learnt shows
IMPROVING = Limits(first_seconds=10.0, improve_seconds=5.0, hold_seconds=0.0)


async def first_and_verdict(model_reference: str, model: Model, config: Path | None = None,
                            limits: Limits = NO_IMPROVEMENT) -> tuple[list[Answer], list[Answer]]:
    """The answers to the request for every operation, asked twice."""
    process = PlannerProcess(model_reference, limits, timing=station_timing(model, config))
    try:
        assert await process.ready(60.0)
        answers = await asyncio.wait_for(collect(process, every_operation(model, 1)), 120)
        again = await asyncio.wait_for(collect(process, every_operation(model, 2)), 120)
        return answers, again
    finally:
        process.close()


def first_plan_and_verdict(answers: list[Answer]) -> tuple[Plan, Verdict]:
    first = answers[0].result
    assert isinstance(first, Plan) and first.execution is STRICTEST, answers[0]
    verdicts = [a.verdict for a in answers if a.verdict is not None]
    assert len(verdicts) == 1 and answers[1].verdict is verdicts[0], answers
    return first, verdicts[0]


async def test_the_planner_process_sends_the_first_plan_at_once_then_its_verdict_and_learns_the_race() -> None:
    model = guarded_station()
    answers, again = await first_and_verdict(GUARDED, model)
    _, verdict = first_plan_and_verdict(answers)
    # The vacuum switched off while the feeder's sensor is due: no order saves the plan.
    refused = verdict.refusal
    assert refused is not None and refused.effect == "g1.release.executing.effect", verdict
    assert verdict.plan.execution is STRICTEST
    # The worker learnt the race: the same request again gets a plan no timing breaks in the engine's order.
    _, verdict = first_plan_and_verdict(again)
    assert verdict.passed and not verdict.refusals and verdict.plan.execution is DEFAULT_EXECUTION, verdict


async def test_the_feeder_stations_first_plan_is_found_safe_in_the_engines_order() -> None:
    model = build_model()
    answers, _ = await first_and_verdict(FEEDER, model, CONFIG, IMPROVING)
    first, verdict = first_plan_and_verdict(answers)
    assert verdict.passed and verdict.plan.execution is DEFAULT_EXECUTION
    assert verdict.plan.steps == first.steps
    # An improvement goes out only checked in the engine's order.
    improvements = [a.result for a in answers[2:] if isinstance(a.result, Plan)]
    assert all(plan.execution is DEFAULT_EXECUTION for plan in improvements), improvements


def test_the_verdict_lets_the_plan_under_way_run_in_the_order_it_allows() -> None:
    model = build_model(feeder_delay=0.05)  # the sensor before the robot moves: every order follows the plan
    stack = build_controller_stack(model)
    clock = VirtualClock()
    core = stack.control_core(clock)
    loop = ControlLoop(core, RunRecorder(core, clock, None), (r.name for r in model.resources), clock)
    loop.request(["Place"])
    loop.tick()
    request = loop.plan_request()
    assert request is not None
    plan = core.solve(request)
    assert isinstance(plan, Plan)
    loop.adopt(request, dataclasses.replace(plan, execution=STRICTEST))
    assert core.progress is not None and core.progress.execution is STRICTEST
    sequence_depends = list(core.progress.depends)
    durations = {e.resource: e.duration for e in durations_of(model).entries}
    verdict = TimedCheck(core.compiled, durations, Execution.PARTIAL_ORDER).verdict(plan)
    assert verdict.passed and verdict.plan.execution is Execution.PARTIAL_ORDER
    # A refused verdict, or one on an older request, changes nothing; the current one loosens the order.
    assert not loop.checked(request, Verdict(verdict.plan, verdict.refusals, passed=False))
    assert not loop.checked(dataclasses.replace(request, generation=request.generation - 1), verdict)
    assert core.progress.execution is STRICTEST
    assert loop.checked(request, verdict)
    progress = core.progress
    assert progress.execution is Execution.PARTIAL_ORDER and progress.plan.execution is Execution.PARTIAL_ORDER
    assert any(loose < strict for loose, strict in zip(progress.depends, sequence_depends, strict=True))


@pytest.mark.slow
async def test_hubctl_up_checks_its_plans_in_time_and_ends_with_the_cycle_report(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The feeder station as processes over Zenoh: its controller's planner process checks the plan in time and
    lets it run in the engine's order; `hubctl up` prints the cycle report at the end; the recording, verdict
    included, replays to the same decisions."""
    lines = await up(CONFIG, tmp_path, monkeypatch, 120.0)
    output = "\n".join(lines)
    report = next(i for i, line in enumerate(lines) if line.startswith("cycle "))
    assert "bound" in lines[report] and "cycle/bound" in lines[report], output
    assert {line.split()[0] for line in lines[report + 1:report + 4]} == {"r", "g", "f"}, output
    controller_log = (tmp_path / "controller.log").read_text()
    assert f"plan checked in time: it runs in {DEFAULT_EXECUTION}" in controller_log, controller_log[-3000:]
    (recording,) = (tmp_path / "runs").glob("*.sqlite")
    with open_run(recording) as run:
        replayed = Replayer(run).replay()
    assert replayed.same, str(replayed.divergence)


def test_a_newer_request_stops_the_check_under_way() -> None:
    """The planner process's check looks at the request pipe as it goes: a newer request ends it."""
    model = guarded_station()
    stack = build_controller_stack(model)
    request = every_operation(model, 1)
    plan = stack.planner.plan(request.start, dict(request.goals))
    assert isinstance(plan, Plan)
    check = TimedCheck(stack.compiled, station_timing(model).durations)
    with pytest.raises(CheckStopped):
        check.verdict(plan, stop=lambda: True)
    assert check.verdict(plan, stop=lambda: False).plan.steps == plan.steps  # not stopped, it has its verdict
