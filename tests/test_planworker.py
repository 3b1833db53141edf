"""The planner process: ready before the controller plans, and a newer request preempts the improvement
of an older one at a safe point (controller/planworker.py, controller/preemption.py), with nothing half
built kept."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from common.model import OperationState
from common.stations import engine_assembly
from controller.control import PlanRequest
from controller.planner import Plan
from controller.planworker import Answer, Limits, PlannerProcess
from controller.stack import build_controller_stack
from deploy.local.statefile import load_state

MODEL = "common.stations.engine_assembly:build_model"
ROBOT_HOME_STATE = Path(__file__).parent / "bench" / "robothome_state.toml"

pytestmark = pytest.mark.timeout(120)


def robot_home_request(generation: int) -> PlanRequest:
    """`RobotHome` from the state where the old A* stalled: a first plan in milliseconds, then an
    improvement (A*'s tables for the goal, then about 10,000 expansions) that takes seconds."""
    model = engine_assembly.build_model()
    compiled = build_controller_stack(model).compiled
    values = model.initial_state()
    values.update(load_state(str(ROBOT_HOME_STATE), model))
    op = model.operation_by_name["RobotHome"]
    values[op.state_path] = OperationState.EXECUTING.value
    return PlanRequest(generation, compiled.pack(values), {"RobotHome": op.goal}, frozenset())


async def collect(process: PlannerProcess, request: PlanRequest, first: asyncio.Event | None = None) -> list[Answer]:
    answers = []
    async for answer in process.answers(request):
        answers.append(answer)
        if first is not None:
            first.set()
    return answers


async def test_a_newer_request_preempts_the_improvement_and_is_answered() -> None:
    process = PlannerProcess(MODEL, Limits(first_seconds=30.0, improve_seconds=60.0, hold_seconds=0.0))
    try:
        assert await process.ready(60.0), "the planner process never reported its tables built"
        assert process.ready_seconds is not None and process.ready_seconds > 0
        old = robot_home_request(1)
        first_answer = asyncio.Event()
        improving = asyncio.create_task(collect(process, old, first_answer))
        await asyncio.wait_for(first_answer.wait(), 60)
        # The first plan is out; the worker now improves it. A newer request arrives.
        newer = robot_home_request(2)
        answered = await asyncio.wait_for(collect(process, newer), 60)
        old_answers = await asyncio.wait_for(improving, 60)

        first = old_answers[0].result
        assert isinstance(first, Plan) and first.steps and not first.stats.minimal
        assert old_answers[-1].final and old_answers[-1].preempted, \
            f"the improvement was not preempted: {[(a.final, a.preempted, a.result) for a in old_answers]}"
        plans = [a.result for a in answered if isinstance(a.result, Plan)]
        assert plans and all(p.steps for p in plans), answered
        assert not answered[-1].preempted

        # Nothing half built was kept: the same goals asked with time to finish get the shortest plan,
        # shown minimal, no longer than the first one (17 steps from this state).
        final = await asyncio.wait_for(collect(process, robot_home_request(3)), 60)
        best = [a.result for a in final if isinstance(a.result, Plan)][-1]
        assert best.stats.minimal and len(best.steps) == 17, (len(best.steps), best.stats)
        assert not final[-1].preempted
    finally:
        process.close()


async def test_a_request_while_nothing_is_improved_is_not_preempted() -> None:
    """Requests one after another, each arriving while the worker is idle: each gets its answers, none of
    them `preempted`."""
    process = PlannerProcess(MODEL, Limits(first_seconds=30.0, improve_seconds=0.5, hold_seconds=0.0))
    try:
        assert await process.ready(60.0)
        for generation in (1, 2, 3):
            answers = await asyncio.wait_for(collect(process, robot_home_request(generation)), 60)
            assert isinstance(answers[0].result, Plan)
            assert not any(a.preempted for a in answers), answers
    finally:
        process.close()
