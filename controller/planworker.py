"""The planner in a process of its own, answering anytime.

A search is pure Python and holds the GIL: in a thread it would starve the tick loop
and the state ingestion (hubs would look stale while the controller plans). The worker
builds the same model, supervisor and planner once, keeps its caches warm across
requests, and streams its answers to each request: the first valid plan as soon as the
satisficing member has one, then each shorter plan the portfolio finds.

A newer request preempts the improvement of an older one at once: the controller follows
each request with a signal, and while the worker improves an answer already sent (A*
building its tables for a new goal set takes up to a second, in loops that look at no
clock) the signal ends that work where it is (`preemption.py`). The first answer is never
preempted, so every request gets one; the improvement's half-built tables are dropped.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
import multiprocessing
import os
import threading
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass
from multiprocessing.connection import Connection

from common.wire.ctl import PlannedAlone

from .control import FIRST_ANSWER_S, HOLD_S, IMPROVE_S, PlanRequest, anytime_answers, live_budget
from .planner import NoPlan, Plan, Planner
from .preemption import PREEMPT_SIGNAL, Preempted, Preemption

log = logging.getLogger(__name__)

READY_WAIT_S = 60.0  # how long the controller waits for the worker's tables before it plans anyway
COLLECTOR_THRESHOLDS = (20_000, 50, 1000)
COLLECT_EVERY = 16  # requests between full collections, made while the worker is idle


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
    preempted: bool = False  # with `final`: a newer request ended the improvement of this one


@dataclass(frozen=True)
class Ready:
    """The worker's tables are built and it takes requests (and preemption signals)."""

    seconds: float


def _answer(planner: Planner, request: PlanRequest, limits: Limits, requests: Connection, answers: Connection,
            preemption: Preemption, graveyard: list[object]) -> None:
    """Stream the answers to one request until the portfolio is done or a newer request waits. What a
    preempted search left behind (`graveyard`) is freed once this request has its first answer."""
    budget = live_budget(limits.first_seconds, limits.improve_seconds, limits.hold_seconds, stop=requests.poll)
    found = anytime_answers(planner, request, budget)
    first = True
    try:
        while True:
            with preemption.allowed(not first):  # improving an answer already sent: a newer request ends it
                item = next(found, None)
            if item is None:
                return
            answers.send(Answer(request.generation, *item))
            first = False
            graveyard.clear()
            if requests.poll():
                return
    finally:
        found.close()


def quiet_collector() -> None:
    """The model and its tables live as long as the worker: out of the collector's passes. A search
    allocates millions of short-lived objects; with the default thresholds the collector took 16 % of
    a search's time in passes of up to 100 ms, during which no preemption signal is handled either."""
    gc.freeze()
    gc.set_threshold(*COLLECTOR_THRESHOLDS)


def _serve(requests: Connection, answers: Connection, model_reference: str, limits: Limits) -> None:
    # Before anything slow: from the Ready message on, the controller signals every new request.
    preemption = Preemption(requests)
    began = time.perf_counter()
    from common.stations import load_model

    from .stack import build_controller_stack

    # The satisficing member's tables are built before the first request.
    planner = build_controller_stack(load_model(model_reference), prepare=True).planner
    quiet_collector()
    answers.send(Ready(time.perf_counter() - began))
    served = 0
    # A preempted search's frames (its open list, its closed states) and dropped tables: freeing them costs
    # up to ~150 ms, which would come before the new request's first answer; they are kept until it is sent.
    graveyard: list[object] = []
    while True:
        if served % COLLECT_EVERY == COLLECT_EVERY - 1 and not requests.poll():
            gc.collect()  # between requests, while none waits: the generous thresholds leave cycles behind
        served += 1
        request: PlanRequest | None = requests.recv()
        while request is not None and requests.poll():
            request = requests.recv()  # only the newest request matters
        if request is None:
            return
        preempted = False
        try:
            _answer(planner, request, limits, requests, answers, preemption, graveyard)
        except Preempted as interrupted:
            # Wherever it stopped, the A* tables under construction may be half built: dropped. The
            # traceback holds the interrupted frames and their locals: into the graveyard with the tables.
            graveyard += [interrupted, *planner.forget_partial_work()]
            preempted = True
        except Exception as exc:  # a planner bug must not stop the station: the controller reports it
            log.exception("planner failed")
            answers.send(Answer(request.generation, NoPlan(f"planner failed: {type(exc).__name__}: {exc}",
                                                           tuple(request.goals))))
        answers.send(Answer(request.generation, None, final=True, preempted=preempted))


class PlannerProcess:
    """The controller's side: `answers(request)` yields the worker's answers to that request."""

    def __init__(self, model_reference: str, limits: Limits | None = None) -> None:
        self.model_reference = model_reference
        self.limits = limits or Limits()
        self._queues: dict[int, asyncio.Queue[Answer]] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._process: multiprocessing.process.BaseProcess | None = None
        self._send: Connection | None = None
        self._ready = threading.Event()
        self.ready_seconds: float | None = None
        self._start()

    def _start(self) -> None:
        context = multiprocessing.get_context("spawn")
        worker_requests, self._send = context.Pipe(duplex=False)
        receive, worker_answers = context.Pipe(duplex=False)
        self._ready.clear()
        self._process = context.Process(target=_serve, name="planner", daemon=True,
                                        args=(worker_requests, worker_answers, self.model_reference, self.limits))
        self._process.start()
        worker_requests.close()
        worker_answers.close()
        threading.Thread(target=self._read, args=(receive,), name="planner-answers", daemon=True).start()

    def _read(self, receive: Connection) -> None:
        while True:
            try:
                answer: Answer | Ready = receive.recv()
            except (EOFError, OSError):
                self._ready.set()  # nobody waits for a worker that is gone
                self._deliver_to_all("the planner process ended")
                return
            if isinstance(answer, Ready):
                self.ready_seconds = answer.seconds
                self._ready.set()
            elif self._loop is not None:
                self._loop.call_soon_threadsafe(self._deliver, answer)

    async def ready(self, timeout: float = READY_WAIT_S, stop: asyncio.Event | None = None) -> bool:
        """Wait until the worker has built its tables (True), or `timeout` seconds or `stop` (False). Polls:
        a thread blocked in `Event.wait` would hold up the process's exit if it is stopped meanwhile."""
        deadline = time.monotonic() + timeout
        while not self._ready.is_set() and time.monotonic() < deadline and not (stop is not None and stop.is_set()):
            await asyncio.sleep(0.02)
        return self._ready.is_set() and self.ready_seconds is not None

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

    def _preempt(self) -> None:
        """Tell the worker a request is waiting (it ends an improvement under way; otherwise nothing)."""
        process = self._process
        if process is None or process.pid is None or not self._ready.is_set() or not process.is_alive():
            return  # before Ready the worker's handler may not be installed: the signal would kill it
        with contextlib.suppress(ProcessLookupError):
            os.kill(process.pid, PREEMPT_SIGNAL)

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
            self._preempt()
            while True:
                answer = await queue.get()
                if answer.result is not None or not answer.final or answer.preempted:
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
