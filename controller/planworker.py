"""The planner in a process of its own.

A search is pure Python and holds the GIL: in a thread it would starve the tick loop
and the state ingestion (hubs would look stale while the controller plans). The worker
builds the same model, supervisor and planner once, keeps its heuristic caches warm
across requests, and answers one request at a time.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import multiprocessing

from .control import PlanRequest, solve_goals
from .planner import NoPlan, Plan, Planner

_planner: Planner | None = None
_limits: tuple[float, float] = (3.0, 10.0)


def _start(model_reference: str, joint_time_limit: float, single_time_limit: float) -> None:
    global _planner, _limits
    from common.model.compiled import CompiledModel
    from common.stations import load_model

    from .synthesis import synthesize

    model = load_model(model_reference)
    supervisor = synthesize(model)
    _planner = Planner(CompiledModel(model, supervisor.guards), supervisor.forbidden)
    _limits = (joint_time_limit, single_time_limit)


def _solve(request: PlanRequest) -> tuple[Plan | NoPlan | None, str]:
    assert _planner is not None, "planner worker not started"
    return solve_goals(_planner, request, *_limits)


class PlannerProcess:
    def __init__(self, model_reference: str, joint_time_limit: float = 3.0, single_time_limit: float = 10.0) -> None:
        self.pool = concurrent.futures.ProcessPoolExecutor(
            max_workers=1, mp_context=multiprocessing.get_context("spawn"), initializer=_start,
            initargs=(model_reference, joint_time_limit, single_time_limit))

    async def solve(self, request: PlanRequest) -> tuple[Plan | NoPlan | None, str]:
        return await asyncio.get_running_loop().run_in_executor(self.pool, _solve, request)

    def close(self) -> None:
        self.pool.shutdown(wait=False, cancel_futures=True)
