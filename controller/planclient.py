"""The live controller's planning, off its event loop: one request at a time until it has its first answer,
its improvements taken while they come.

A request goes to the planner process (a search holds the GIL; controller/planworker.py) or, without one,
to a thread. Its first answer is adopted (a plan, or no plan: the operations' error); a newer request may
go out as soon as it is, and the worker then drops the older one's improvements. A shorter plan that
comes later is taken if it is still valid from the measured state (`ControlCore.improve`).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

from common.wire.ctl import NoPlanFound, PlannedAlone

from .control import PlanRequest
from .loop import ControlLoop
from .planner import NoPlan, Plan
from .planworker import PlannerProcess
from .timed_check import Verdict

log = logging.getLogger("statehub.controller")


class PlanClient:
    def __init__(self, loop: ControlLoop, planner_process: PlannerProcess | None, wake: Callable[[], None]) -> None:
        """`wake()`: asks for a tick now (a plan was taken, or a newer request may go out)."""
        self.loop = loop
        self.planner_process = planner_process
        self.wake = wake
        self.usable = False  # until the planner process has its tables (the service's `_planner_ready`)
        self._planning: asyncio.Task[None] | None = None  # until the request under way has its first answer
        self._solving: set[asyncio.Task[None]] = set()  # requests whose answers are still coming

    def tasks(self) -> list[asyncio.Task[None]]:
        """The tasks under way, for the service to cancel when it stops."""
        return [*([self._planning] if self._planning is not None else []), *self._solving]

    def maybe_plan(self) -> None:
        """Ask for a plan if one is due, the planner usable and no request waits for its first answer."""
        if self._planning is not None or not self.usable:
            return
        request = self.loop.plan_request()
        if request is None:
            return
        first_answered = asyncio.Event()
        task = asyncio.create_task(self._solve(request, first_answered), name=f"plan-{request.generation}")
        self._solving.add(task)
        task.add_done_callback(self._solving.discard)
        self._planning = asyncio.create_task(self._first(first_answered), name="plan")

    async def _first(self, first_answered: asyncio.Event) -> None:
        # A newer request may go out as soon as this one has its first answer; the worker then
        # drops the improvement of this one.
        await first_answered.wait()
        self._planning = None
        self.wake()

    async def _solve(self, request: PlanRequest, first_answered: asyncio.Event) -> None:
        try:
            if self.planner_process is not None:
                async for answer in self.planner_process.answers(request):
                    if answer.verdict is not None:
                        self._checked(request, answer.verdict)
                        continue
                    if answer.note is not None:
                        self.loop.note(answer.note)
                    if not first_answered.is_set():
                        self._adopt(request, answer.result, answer.note)
                        first_answered.set()
                    elif isinstance(answer.result, Plan) and self.loop.improve(request, answer.result):
                        log.info("better plan taken: %d steps (%s)", len(answer.result.steps),
                                 answer.result.stats.method)
                        self.wake()
            else:
                self._adopt(request, await asyncio.to_thread(self.loop.core.solve, request))
        except Exception as exc:  # a planner bug must not stop the station: report and retry
            log.exception("planner failed")
            if not first_answered.is_set():
                self._adopt(request, NoPlan(f"planner failed: {type(exc).__name__}: {exc}", tuple(request.goals)))
        finally:
            first_answered.set()

    def _checked(self, request: PlanRequest, verdict: Verdict) -> None:
        """The timed check's verdict on the first plan, which runs in the strictest order until it comes."""
        refused = verdict.refusal
        if refused is not None:
            log.warning("the plan loses a race in every order (it runs step after step; the planner learns the "
                        "race for the next plans): %s", refused.text)
        elif self.loop.checked(request, verdict) and verdict.plan.execution is not None:
            log.info("plan checked in time: it runs in %s", verdict.plan.execution.value)
            self.wake()

    def _adopt(self, request: PlanRequest, result: Plan | NoPlan | None, note: PlannedAlone | None = None) -> None:
        for event in self.loop.adopt(request, result, note).events:
            if isinstance(event, NoPlanFound):  # once per goal and reason, not at every retry
                log.warning("%s", event.text)
        if isinstance(result, Plan):
            stats = result.stats
            log.info("plan: %d steps for %d goals in %.1f ms (%s%s; %s)", len(result.steps), len(request.goals),
                     stats.seconds * 1000, stats.method, ", shortest" if stats.minimal else "", request.reason.text)
        self.wake()
