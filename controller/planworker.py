"""The planner in a process of its own, answering anytime.

A search is pure Python and holds the GIL: in a thread it would starve the tick loop
and the state ingestion (hubs would look stale while the controller plans). The worker
builds the same model, supervisor and planner once, keeps its caches warm across
requests, and streams its answers to each request: the first valid plan as soon as the
satisficing member has one, then each shorter plan the portfolio finds. A newer request
stops the improvement of an older one at once.
"""

from __future__ import annotations

import asyncio
import logging
import multiprocessing
import threading
from collections.abc import AsyncIterator
from dataclasses import dataclass
from multiprocessing.connection import Connection

from common.ctl import PlannedAlone

from .control import FIRST_ANSWER_S, HOLD_S, IMPROVE_S, PlanRequest, anytime_answers, live_budget
from .planner import NoPlan, Plan

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Limits:
    first_seconds: float = FIRST_ANSWER_S
    improve_seconds: float = IMPROVE_S
    hold_seconds: float = HOLD_S


@dataclass(frozen=True)
class Answer:
    generation: int
    result: Plan | NoPlan | None  # None with `final`: nothing more for this request
    note: PlannedAlone | None = None
    final: bool = False


def _serve(requests: Connection, answers: Connection, model_reference: str, limits: Limits) -> None:
    from common.stations import load_model

    from .stack import build_controller_stack

    # The satisficing member's tables are built before the first request.
    planner = build_controller_stack(load_model(model_reference), prepare=True).planner
    while True:
        request: PlanRequest | None = requests.recv()
        while request is not None and requests.poll():
            request = requests.recv()  # only the newest request matters
        if request is None:
            return
        budget = live_budget(limits.first_seconds, limits.improve_seconds, limits.hold_seconds, stop=requests.poll)
        try:
            for result, note in anytime_answers(planner, request, budget):
                answers.send(Answer(request.generation, result, note))
                if requests.poll():
                    break
        except Exception as exc:  # a planner bug must not stop the station: the controller reports it
            log.exception("planner failed")
            answers.send(Answer(request.generation, NoPlan(f"planner failed: {type(exc).__name__}: {exc}",
                                                           tuple(request.goals))))
        answers.send(Answer(request.generation, None, final=True))


class PlannerProcess:
    """The controller's side: `answers(request)` yields the worker's answers to that request."""

    def __init__(self, model_reference: str, limits: Limits | None = None) -> None:
        self.model_reference = model_reference
        self.limits = limits or Limits()
        self._queues: dict[int, asyncio.Queue[Answer]] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._process: multiprocessing.process.BaseProcess | None = None
        self._send: Connection | None = None
        self._start()

    def _start(self) -> None:
        context = multiprocessing.get_context("spawn")
        worker_requests, self._send = context.Pipe(duplex=False)
        receive, worker_answers = context.Pipe(duplex=False)
        self._process = context.Process(target=_serve, name="planner", daemon=True,
                                        args=(worker_requests, worker_answers, self.model_reference, self.limits))
        self._process.start()
        worker_requests.close()
        worker_answers.close()
        threading.Thread(target=self._read, args=(receive,), name="planner-answers", daemon=True).start()

    def _read(self, receive: Connection) -> None:
        while True:
            try:
                answer: Answer = receive.recv()
            except (EOFError, OSError):
                self._deliver_to_all("the planner process ended")
                return
            if self._loop is not None:
                self._loop.call_soon_threadsafe(self._deliver, answer)

    def _deliver(self, answer: Answer) -> None:
        queue = self._queues.get(answer.generation)
        if queue is not None:
            queue.put_nowait(answer)

    def _deliver_to_all(self, why: str) -> None:
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        for generation in list(self._queues):
            answer = Answer(generation, NoPlan(why), final=True)
            loop.call_soon_threadsafe(self._deliver, answer)

    async def answers(self, request: PlanRequest) -> AsyncIterator[Answer]:
        self._loop = asyncio.get_running_loop()
        if self._process is None or not self._process.is_alive():
            log.warning("planner process is not running: starting it again")
            self._start()
        queue: asyncio.Queue[Answer] = asyncio.Queue()
        self._queues[request.generation] = queue
        try:
            assert self._send is not None
            self._send.send(request)
            while True:
                answer = await queue.get()
                if answer.result is not None or not answer.final:
                    yield answer
                if answer.final:
                    return
        finally:
            self._queues.pop(request.generation, None)

    def close(self) -> None:
        try:
            if self._send is not None:
                self._send.send(None)
                self._send.close()
        except OSError:
            pass
        if self._process is not None:
            self._process.join(timeout=2.0)
            if self._process.is_alive():
                self._process.kill()
