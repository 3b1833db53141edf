"""The planner in a process of its own, answering anytime.

A search is pure Python and holds the GIL: in a thread it would starve the tick loop
and the state ingestion (hubs would look stale while the controller plans). The worker
builds the same model, supervisor and planner once, keeps its caches warm across
requests, and streams its answers to each request: the first valid plan as soon as the
satisficing member has one, then each shorter plan the portfolio finds, and last the best of them in an order the
engine finishes sooner, if the member that improves plans by time finds one (controller/retime.py).

A newer request preempts the improvement of an older one: the searches and the table builders
look at the request pipe as they go (`preemption.py`) and end at their next safe point, keeping
every table they had finished and none half built. The first answer is never preempted, so
every request gets one.

Plans checked in time (controller/timed_check.py), given the station's durations: the check of a plan of
hundreds of steps takes seconds, which the controller's event loop cannot spare and a first answer must not
wait for. The first plan goes out at once, to run in the strictest order (`Execution.SEQUENCE`: each step
after the one before) until its verdict; the worker then checks it, a newer request stopping the check, and
sends the verdict: the order it is safe in, the controller's own or a stricter one (`ControlLoop.checked`),
or the race it loses in every order, which the worker's planner learns for the requests to come. An
improvement goes out only if the controller's own order follows it at every timing. Here rather than in a
thread of the controller: the check is pure Python and would hold the GIL the tick loop needs; and the
planner that learns a lost race is this one.
"""

from __future__ import annotations

import asyncio
import gc
import logging
import multiprocessing
import threading
import time
from collections.abc import AsyncIterator, Mapping
from dataclasses import dataclass, replace
from multiprocessing.connection import Connection

from common.config.modes import DEFAULT_EXECUTION
from common.model import Duration, Model
from common.wire.ctl import PlannedAlone

from .control import PlanRequest
from .deorder import Execution
from .planner import NoPlan, Plan, Planner
from .planner.policy import (
    FIRST_ANSWER_S,
    FIRST_RETIME_S,
    HOLD_S,
    IMPROVE_S,
    RETIME_LIVE_TRIES,
    RETIME_S,
    anytime_answers,
    live_budget,
    solve_goals,
)
from .preemption import NewerRequest
from .retime import Retimer, longest_seconds
from .timed_check import STRICTEST, CheckStopped, TimedCheck, Verdict, learn_race, revalidation

log = logging.getLogger(__name__)

READY_WAIT_S = 60.0  # how long the controller waits for the worker's tables before it plans anyway
COLLECTOR_THRESHOLDS = (20_000, 50, 1000)
COLLECT_EVERY = 16  # requests between full collections, made while the worker is idle


@dataclass(frozen=True)
class Limits:
    first_seconds: float = FIRST_ANSWER_S
    improve_seconds: float = IMPROVE_S
    hold_seconds: float = HOLD_S
    retime_seconds: float = RETIME_S  # then the member that improves the best plan by time (0: none)
    first_retime_seconds: float = FIRST_RETIME_S  # and the first plan, before it goes out


@dataclass(frozen=True)
class Timing:
    """What the worker checks plans against: each resource's effect durations (common/resources' `durations_of`:
    the model's, hubs.toml's `delay` over them; `DurationTable.keyed()`, with the effects whose ability takes its
    own time) and the controller engine's own order."""

    durations: Mapping[str, Duration]
    execution: Execution = DEFAULT_EXECUTION


@dataclass(frozen=True)
class Answer:
    generation: int
    result: Plan | NoPlan | None  # None with `final`: nothing more for this request
    note: PlannedAlone | None = None
    final: bool = False
    preempted: bool = False  # with `final`: a newer request ended the improvement of this one
    verdict: Verdict | None = None  # with no result: the timed check of the request's first plan


class InTime:
    """The worker's timed check: its planner's revalidation of a kept rest, and what a lost race teaches it."""

    def __init__(self, model: Model, planner: Planner, timing: Timing) -> None:
        self.planner = planner
        self.check = TimedCheck(planner.compiled, timing.durations, timing.execution)
        self.goals = {name: op.goal for name, op in model.operation_by_name.items()}
        self.retimer = Retimer(planner, longest_seconds(planner.compiled, timing.durations), timing.execution)

    def sooner(self, plan: Plan, request: PlanRequest, requests: Connection, seconds: float) -> Plan | None:
        """The plan's steps in an order the engine finishes sooner (controller/retime.py), found within `seconds`, not
        yet checked in time; None if there is none. Raises `CheckStopped` when a newer request waits."""
        if seconds <= 0 or plan.execution is not None:
            return None
        found = self.retimer.faster(plan, request, RETIME_LIVE_TRIES, deadline=time.perf_counter() + seconds,
                                    stop=requests.poll)
        if found is None:
            if requests.poll():
                raise CheckStopped
            return None
        log.info("plan retimed: %d steps predicted to end in %.1f s instead of %.1f s (%d orders tried)",
                 len(found.plan.steps), found.after_s, found.before_s, found.tried)
        return found.plan

    def faster(self, plan: Plan, request: PlanRequest, requests: Connection, seconds: float) -> Plan | None:
        """`sooner`, and only if the engine's own order follows it at every timing of its effects."""
        sooner = self.sooner(plan, request, requests, seconds)
        if sooner is None:
            return None
        verdict = self.verdict(sooner, request, requests, stricter=False)
        # in the engine's own order: a faster plan is no gain if it needs a stricter one
        return verdict.plan if verdict.passed else None

    def verdict(self, plan: Plan, request: PlanRequest, requests: Connection, *, stricter: bool) -> Verdict:
        """Raises `CheckStopped` when a newer request waits."""
        return self.check.verdict(plan, request.disabled, revalidation(self.planner, self.goals, plan,
                                                                       request.disabled),
                                  requests.poll, stricter=stricter)

    def learn(self, verdict: Verdict, request: PlanRequest) -> None:
        refused = verdict.refusal
        if refused is not None and learn_race(self.planner, self.planner.compiled, refused, request.goals,
                                              request.disabled):
            log.info("race learnt: %s", refused.text)


@dataclass(frozen=True)
class Ready:
    """The worker's tables are built and it takes requests."""

    seconds: float


def _answer(planner: Planner, request: PlanRequest, limits: Limits, requests: Connection, answers: Connection,
            graveyard: list[object], in_time: InTime | None = None) -> bool:
    """Stream the answers to one request until the portfolio is done or a newer request waits; True when
    a newer request ended the improvement. What a stopped search left (`graveyard`: its open list and
    closed states) is freed once the next request has its first answer. `in_time`: plans checked in time."""
    newer = NewerRequest(requests)
    leftovers: list[object] = []
    budget = live_budget(limits.first_seconds, limits.improve_seconds, limits.hold_seconds, stop=newer,
                         leftovers=leftovers)
    found = anytime_answers(planner, request, budget)
    first = True
    best: Plan | None = None  # the last plan the portfolio found
    try:
        for plan, note in found:
            if in_time is None:
                answers.send(Answer(request.generation, plan, note))
            elif first:
                _first_in_time(plan, note, request, limits, requests, answers, in_time)
            elif isinstance(plan, Plan):
                verdict = in_time.verdict(plan, request, requests, stricter=False)
                if verdict.passed:  # a shorter plan is no gain if it needs a stricter order
                    answers.send(Answer(request.generation, verdict.plan, note))
            best = plan if isinstance(plan, Plan) else best
            first = False
            newer.arm()
            graveyard.clear()
            if requests.poll():
                return True
        if newer.stopped:
            return True
        if in_time is not None and best is not None:
            faster = in_time.faster(best, request, requests, limits.retime_seconds)
            if faster is not None:
                answers.send(Answer(request.generation, faster))
        return False
    except CheckStopped:
        return True
    finally:
        found.close()
        graveyard += leftovers


def _first_in_time(plan: Plan | NoPlan | None, note: PlannedAlone | None, request: PlanRequest, limits: Limits,
                   requests: Connection, answers: Connection, in_time: InTime) -> None:
    """The first answer at once, a plan to run in the strictest order; then its verdict."""
    races = in_time.planner.timed_races
    if isinstance(plan, NoPlan) and races:
        # No plan wins every race learnt: the one that loses one is all there is. It runs, fails, and the
        # livelock watch names the effect it lost (as `ControlLoop.solve` does).
        with races.suspended_while():
            plan, note = solve_goals(in_time.planner, request, live_budget(limits.first_seconds, 0.0, 0.0))
    if not isinstance(plan, Plan):
        answers.send(Answer(request.generation, plan, note))
        return
    # The same steps in a faster order, if a short look finds one: a faster order that comes later finds the
    # devices already on their way in this one.
    plan = in_time.sooner(plan, request, requests, limits.first_retime_seconds) or plan
    answers.send(Answer(request.generation, replace(plan, execution=STRICTEST), note))
    verdict = in_time.verdict(plan, request, requests, stricter=True)
    answers.send(Answer(request.generation, None, verdict=verdict))
    in_time.learn(verdict, request)


def quiet_collector() -> None:
    """The model and its tables live as long as the worker: out of the collector's passes. A search
    allocates millions of short-lived objects; with the default thresholds the collector took 16 % of
    a search's time in passes of up to 100 ms, during which a newer request waits too."""
    gc.freeze()
    gc.set_threshold(*COLLECTOR_THRESHOLDS)


def _serve(requests: Connection, answers: Connection, model_reference: str, limits: Limits,
           timing: Timing | None = None) -> None:
    began = time.perf_counter()
    from common.stations import load_model

    from .stack import build_controller_stack

    # The satisficing member's tables are built before the first request.
    model = load_model(model_reference)
    planner = build_controller_stack(model, prepare=True).planner
    in_time = None if timing is None else InTime(model, planner, timing)
    quiet_collector()
    answers.send(Ready(time.perf_counter() - began))
    served = 0
    # A stopped search's open list and closed states: freeing them costs ~30 ms per second it searched,
    # which would come before the newer request's first answer; they are kept until that is sent.
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
            preempted = _answer(planner, request, limits, requests, answers, graveyard, in_time)
        except Exception as exc:  # a planner bug must not stop the station: the controller reports it
            log.exception("planner failed")
            answers.send(Answer(request.generation, NoPlan(f"planner failed: {type(exc).__name__}: {exc}",
                                                           tuple(request.goals))))
        answers.send(Answer(request.generation, None, final=True, preempted=preempted))


class PlannerProcess:
    """The controller's side: `answers(request)` yields the worker's answers to that request."""

    def __init__(self, model_reference: str, limits: Limits | None = None, timing: Timing | None = None) -> None:
        """`timing`: plans checked in time against it (None: not checked)."""
        self.model_reference = model_reference
        self.limits = limits or Limits()
        self.timing = timing
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
                                        args=(worker_requests, worker_answers, self.model_reference, self.limits,
                                              self.timing))
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

    async def answers(self, request: PlanRequest) -> AsyncIterator[Answer]:
        self._loop = asyncio.get_running_loop()
        if self._process is None or not self._process.is_alive():
            log.warning("planner process is not running: starting it again")
            self._start()
        queue: asyncio.Queue[Answer] = asyncio.Queue()
        self._queues[request.generation] = queue
        try:
            assert self._send is not None
            self._send.send(request)  # the worker sees it waiting and ends an improvement under way
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
