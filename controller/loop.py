"""The controller's loop without I/O: what the Zenoh controller (controller/service.py), the in-process
runner (deploy/local/inprocess.py) and `hubctl replay` (deploy/replay/replay.py) each drive.

One step at a time, each in its order: measured values and the hubs' states in (`ingest`), a tick with
the watchdog's unhealthy resources and the held ones (`tick`: the engine, then the commands that
changed), the periodic resend of every command (`resend`), a plan request when one is due
(`plan_request`) and its answers (`adopt` the first, `improve` with a shorter one). At each, the run
recording hears what it took in and what was decided (controller/recording/hooks.py): since every shell goes
through here, a replay's records compare one to one with the recording's.

It owns no clock and no bus: `clock` is read once as each ingest and tick begins (the live controller's
`StepClock.advance`, a virtual clock elsewhere), and it returns the commands to send (the outbox's
`Command`s) and the events logged, for its shell to publish, print or only record.

A station running orders (`run_orders`) finishes and starts them here, after each tick, so that every shell
does it at the same point: the order book commits the transition, then the core takes the product's new
values as a `restore` (its operations finished -> initial are recorded as any operation transition) and the
operations of the next order are requested.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

from common.model import Duration, OperationState, TransitionKind, Value
from common.model.durations import effect_owner
from common.wire.ctl import (
    ConsoleEvent,
    ConsoleReply,
    ConsoleRequest,
    HubAlive,
    HubGone,
    OrderFinished,
    OrderStarted,
    PlannedAlone,
    SupervisorCalled,
    SupervisorCallEnded,
)
from controller.recording.hooks import ALL_HEALTHY, RunRecorder
from controller.recording.schema import HubState

from .causal_chain import CausalChain
from .control import ControlCore, FinishEstimate, PlanRequest
from .cycle import (
    CycleRecord,
    CycleReport,
    effect_seconds,
    lower_bound,
    predicted_finish,
    shortest_seconds,
    step_seconds,
)
from .deorder import order
from .engine import PlanProgress, TickResult
from .exclusions import RunLog, exclusion_bound
from .outbox import Command, CommandVariable, Outbox
from .planner import NoPlan, Plan
from .planner.plans import Execution
from .planner.policy import solve_goals
from .production.flow import OrderFlow
from .production.settle import ProductSettle
from .production.throughput import order_line
from .recording.schema import RunOutcome
from .requests import Requests
from .retime import Retimer
from .timed_check import STRICTEST, Revalidate, TimedCheck, TimingRefusal, Verdict, learn_race, revalidation

NOT_HELD: frozenset[str] = frozenset()
LEARN_PER_REQUEST = 8  # races learnt from plans refused in time before one request takes what it has
LEARNT_SEARCH_SHARE = 10  # of the satisficing member's budget, what a search with races learnt may spend
FINISHED = OperationState.FINISHED.value  # an operation variable's value once it finished


@dataclass(frozen=True)
class Ticked:
    """A tick's result, and the commands whose values it (or anything since the last send) changed."""

    result: TickResult
    commands: list[Command]
    orders: list[OrderStarted | OrderFinished] = field(default_factory=list)  # orders finished and started


@dataclass(frozen=True)
class Adopted:
    """A plan answer handed to the core: whether it was taken, and the events the core logged for it."""

    taken: bool
    events: list[ConsoleEvent]


class ControlLoop:
    def __init__(self, core: ControlCore, recorder: RunRecorder, commanded: Iterable[str],
                 clock: Callable[[], float], seconds: Mapping[str, float] | None = None,
                 durations: Mapping[str, Duration] | None = None, shortest: Mapping[str, float] | None = None) -> None:
        """`commanded`: the resources whose commands are sent (in the model's order, whichever order this is);
        `clock`: read as each step begins; `seconds`: each effect's duration (controller/cycle.py; default:
        the model's longest), for the plans' predicted finish; `shortest`: each effect's least (default: the
        model's, or `seconds` where that is less), for the bounds; `durations`: each resource's interval (and the
        effects' whose ability takes its own: `DurationTable.keyed()`), what
        plans are checked in time against before use (controller/timed_check.py; None: not checked; the check
        runs in the caller's thread, seconds for a plan of hundreds of steps: in process and in replay, not yet
        in the live controller's event loop)."""
        self.core = core
        self.timed = None if durations is None else TimedCheck(core.compiled, durations, core.engine.execution)
        self.refusals: list[TimingRefusal] = []  # of the plans answered, the timings that broke them
        self._goals = {name: op.goal for name, op in core.model.operation_by_name.items()}
        self.seconds = dict(seconds) if seconds is not None else effect_seconds(core.model)
        self.retimer = Retimer(core.planner, self.seconds, core.engine.execution)
        model_shortest = shortest_seconds(core.model)
        self.shortest = (dict(shortest) if shortest is not None else
                         {name: min(s, self.seconds.get(name, s)) for name, s in model_shortest.items()})
        self.run_log = RunLog(core.compiled, core.state)
        self.cycle = CycleRecord([r.name for r in core.model.resources],
                                 lambda: exclusion_bound(core.compiled, self.run_log, self.shortest))
        self.settle = ProductSettle(core.compiled, self.seconds, core.clock)
        self._counted_plan: PlanProgress | None = None  # the plan whose effects seen happen are counted as work
        self._counted_steps: set[int] = set()
        self._step_seconds: list[float] = []
        self.chain = CausalChain(core.compiled, self.shortest, self.run_log)
        self.recorder = recorder
        self.clock = clock
        model, index = core.model, core.compiled.index
        chosen = set(commanded)
        self.outbox = Outbox({r.name: [CommandVariable(v.name, v.path, index[v.path]) for v in r.commands]
                              for r in model.resources if r.name in chosen})
        self.orders: OrderFlow | None = None  # a station running orders (controller/production/)

    def run_orders(self, flow: OrderFlow) -> None:
        """Finish and start the book's orders after each tick from now on."""
        self.orders = flow

    # --- inputs -------------------------------------------------------------------------
    def request(self, operations: Sequence[str]) -> None:
        """The operations requested at start (persisted, or every one)."""
        self.core.request(*operations)
        self.recorder.requested(operations)

    def ingest(self, measured: Mapping[str, Value], hub_states: Sequence[HubState] = ()) -> dict[str, Value]:
        """Measured values (and each hub state's status and mirrored seq, for the recording); what changed."""
        self.clock()
        before = self.core.state
        changed = self.core.ingest(measured) if measured else {}
        self.recorder.ingested(changed, hub_states)
        if changed:
            self.cycle.measured(self.core.clock(), {path.split(".", 1)[0] for path in changed})
            self.chain.measured(before, self.core.state, changed)
            self.cycle.chained(self.chain.longest)
        return changed

    def liveliness(self, hub: str, alive: bool) -> None:
        self.recorder.liveliness(hub, alive)
        self.core.events.log.emit(HubAlive(hub) if alive else HubGone(hub))

    def supervisor_call(self, hub: str, resource: str, calling: bool) -> None:
        """An operator's call for the supervisor began or ended (its hub's token): logged, decides nothing."""
        self.core.events.log.emit(SupervisorCalled(hub, resource) if calling else SupervisorCallEnded(hub, resource))

    def requests(self, *, persist: Callable[[list[str]], None] = lambda _: None,
                 wake: Callable[[], None] = lambda: None) -> Requests:
        """The console's requests, applied to this loop's core and recorded."""
        return Requests(self.core, persist=persist, wake=wake, answered=self._answered)

    def _answered(self, request: ConsoleRequest, reply: ConsoleReply) -> None:
        self.recorder.request(request, reply)

    # --- the tick and the commands ------------------------------------------------------
    def tick(self, unhealthy: Mapping[str, str] = ALL_HEALTHY, held: frozenset[str] = NOT_HELD) -> Ticked:
        """A tick with the watchdog's verdicts (resource -> why unhealthy) and the held resources disabled."""
        core = self.core
        self.clock()
        core.set_disabled(frozenset(unhealthy) | held)
        result = core.tick()
        self.recorder.ticked(unhealthy)
        for dispatched in result.dispatched:
            self.cycle.dispatched(core.clock(), dispatched.resources, dispatched.waited)
        if result.fired:
            self.chain.fired(result.fired)
            self.cycle.chained(self.chain.longest)
        self._count_effects()
        orders = self._advance_orders() if self.orders is not None else []
        return Ticked(result, self._recorded(self.outbox.changed(core.state, held)), orders)

    # --- orders -------------------------------------------------------------------------
    def _advance_orders(self) -> list[OrderStarted | OrderFinished]:
        """The running order finished if every operation it requests is; the next one started if none runs.
        A restarted controller finds either committed with the product's values: nothing to redo here."""
        flow, core = self.orders, self.core
        assert flow is not None
        news: list[OrderStarted | OrderFinished] = []
        current = flow.current
        if current is not None and self._all_finished(flow.requested) and not self.settle.in_hand(core.state):
            values = core.compiled.unpack(core.state)
            if flow.book.complete(current, values):
                done = flow.book.finish(current, values)
                core.load(done.reset)
                core.requested.clear()
                core.errors.clear()
                core.livelock.finished()  # a new product: no state seen for the last one says anything
                figures = flow.finished_order(done.order, core.clock(), self.cycle.spans)
                self.cycle.forget_before(figures.end)  # the next order's window begins here
                self.run_log.restart(core.state)
                news.append(OrderFinished(done.order.id, done.order.product_id, done.order.variant,
                                          figures.cycle_s, order_line(figures)))
        # A station that runs every operation once (it never had an order) takes an order added meanwhile
        # only when its operations are done: the order's start would reset them.
        if flow.current is None and self._all_finished(core.requested):
            start = flow.book.next()
            if start is not None:
                core.load(start.values)
                core.request(*start.operations)  # not the recording's `requested`: what the controller began with
                flow.started(start.order, start.operations)
                news.append(OrderStarted(start.order.id, start.order.product_id, start.order.variant,
                                         len(start.operations)))
        for event in news:
            core.events.log.emit(event)
        if news:
            self.recorder.after()  # the operations reset and the events, recorded in this tick
        return news

    def _all_finished(self, operations: Iterable[str]) -> bool:
        """`core.op_state(name) is FINISHED` for each, read as the raw values: asked at every tick."""
        state, index = self.core.state, self.core.op_index
        return all(state[index[name]] == FINISHED for name in operations)

    def orders_done(self) -> bool:
        """A station running orders has none running or waiting."""
        return self.orders is not None and self.orders.idle()

    def resend(self, held: frozenset[str] = NOT_HELD, resources: Iterable[str] | None = None) -> list[Command]:
        """Every command (of `resources`, if given) again, at the command rate: between ticks, so a value
        changed since the last tick (a mirror taken, a force) goes out with its new seq here."""
        return self._recorded(self.outbox.every(self.core.state, held, resources))

    def _recorded(self, commands: list[Command]) -> list[Command]:
        for command in commands:
            if command.changed:
                self.recorder.command(command.resource, command.seq)
        return commands

    # --- planning -----------------------------------------------------------------------
    def plan_request(self) -> PlanRequest | None:
        """A planning job, if one is due and none is under way."""
        request = self.core.plan_request()
        if request is not None:
            self.recorder.plan_request(request)
        return request

    def note(self, event: PlannedAlone) -> None:
        """The planner's note on an answer (a goal planned alone), logged before the answer is handed over."""
        self.core.events.log.emit(event)

    def adopt(self, request: PlanRequest, result: Plan | NoPlan | None, note: PlannedAlone | None = None,
              *, checked: bool = False) -> Adopted:
        """The first answer to `request`; `checked`: a plan already checked in time (`solve`)."""
        log = self.core.events.log
        cursor = log.total
        if isinstance(result, Plan) and not checked:
            result, _ = self._in_time(request, result)
        taken = self.core.adopt(request, result)
        self.recorder.plan(request, result, taken=taken, note=note)
        if taken:
            self._estimate()
        return Adopted(taken, log.since(cursor).events)

    def improve(self, request: PlanRequest, better: Plan) -> bool:
        """A shorter or faster plan for `request`, after its first answer; True if taken: only one the engine's own
        order follows at every timing (a kept rest of it runs in the order of the plan under way)."""
        refused = self._refusal(request, better, self.core.engine.execution)
        if refused is not None:
            self.refusals.append(refused)
            self.recorder.plan(request, better, taken=False, improvement=True)
            return False
        taken = self.core.improve(request, better, self._finish_estimate())
        self.recorder.plan(request, better, taken=taken, improvement=True)
        if taken:
            self._estimate()
        return taken

    def checked(self, request: PlanRequest, verdict: Verdict) -> bool:
        """The live controller's planner process checked its first answer to `request` in time after sending it
        (adopted meanwhile in the strictest order): the plan under way, or the rest of it kept, goes on in the
        order the verdict allows. True if that is looser than the one it runs in."""
        self.refusals.extend(verdict.refusals)
        progress, allowed = self.core.progress, verdict.plan.execution
        loosened = not (not verdict.passed or allowed is None or progress is None
                        or request.generation != self.core.generation or progress.execution is not STRICTEST
                        or allowed is STRICTEST or set(progress.plan.goals) != set(verdict.plan.goals))
        if loosened:
            assert progress is not None and allowed is not None
            progress.reorder(self.core.compiled, allowed)
        self.recorder.plan(request, verdict.plan, taken=loosened, checked=True)
        return loosened

    def _refusal(self, request: PlanRequest, plan: Plan, execution: Execution) -> TimingRefusal | None:
        if self.timed is None:
            return None
        return self.timed.refusal(plan, request.disabled, execution, self._revalidation(request, plan))

    def _revalidation(self, request: PlanRequest, plan: Plan) -> Revalidate | None:
        return revalidation(self.core.planner, self._goals, plan, request.disabled)

    def _in_time(self, request: PlanRequest, plan: Plan) -> tuple[Plan, TimingRefusal | None]:
        """The plan, to run in the engine's order if no timing of its effects breaks it there, else in the first
        stricter order none breaks; with the refusal when every order is broken (the plan itself counts on an
        effect waiting). controller/timed_check.py's `TimedCheck.verdict`."""
        if self.timed is None:
            return plan, None
        verdict = self.timed.verdict(plan, request.disabled, self._revalidation(request, plan),
                                     own=self.core.engine.execution)
        self.refusals.extend(verdict.refusals)
        return (plan if not verdict.refusals else verdict.plan), verdict.refusal

    def _learn(self, refused: TimingRefusal, request: PlanRequest) -> bool:
        """Forbid the race a refused plan lost for the planning to come; False if nothing new is learnt."""
        return learn_race(self.core.planner, self.core.compiled, refused, request.goals, request.disabled)

    def solve(self, request: PlanRequest) -> Adopted:
        """Plan `request` here and now, within the core's budget (virtual time: counts, not seconds). A plan that
        every order breaks in time teaches the planner the race it lost, and is planned again without it
        (`LEARN_PER_REQUEST` times at most); then the strictest order runs it, the livelock watch the last line."""
        races = self.core.planner.timed_races
        result = self._solve(request, learnt=bool(races))
        for _ in range(LEARN_PER_REQUEST + 1):
            if isinstance(result, NoPlan) and races:
                # No plan wins every race learnt: the one that loses one is all there is. It runs, fails, and the
                # livelock watch names the effect it lost, as it did before plans were checked in time.
                with races.suspended_while():
                    result = self.core.solve(request)
                if isinstance(result, Plan):
                    result, _ = self._in_time(request, result)
                    return self.adopt(request, result, checked=True)
            if not isinstance(result, Plan):
                break
            checked, refused = self._in_time(request, result)
            if refused is None:
                return self.adopt(request, self._faster(request, checked), checked=True)
            if not self._learn(refused, request):
                return self.adopt(request, checked, checked=True)
            result = self._solve(request, learnt=True)
        return self.adopt(request, result)

    def _finish_estimate(self) -> FinishEstimate:
        """How long a plan's steps not yet done take from now, each effect at its longest, in the order the engine
        runs it: its own, else that of the plan under way (which a rest taken from another plan keeps)."""
        compiled, own = self.core.compiled, self.core.engine.execution
        progress = self.core.progress
        running = progress.plan.execution if progress is not None else None

        def finish(plan: Plan, done: frozenset[int]) -> float:
            durations = step_seconds(compiled, plan, self.seconds)
            left = [0.0 if j in done else seconds for j, seconds in enumerate(durations)]
            return predicted_finish(order(compiled, plan, plan.execution or running or own), left)

        return finish

    def _faster(self, request: PlanRequest, plan: Plan) -> Plan:
        """The same steps in an order the engine finishes sooner (controller/retime.py), if one is found that runs
        in the engine's own order at every timing of its effects (controller/timed_check.py); else `plan`."""
        if plan.execution is not None:  # it runs in a stricter order than the one the finish is predicted in
            return plan
        found = self.retimer.faster(plan, request, self.core.budget.retime_tries)
        if found is None or self._refusal(request, found.plan, self.core.engine.execution) is not None:
            return plan
        return found.plan

    def _solve(self, request: PlanRequest, *, learnt: bool) -> Plan | NoPlan | None:
        """`learnt`: with races learnt, a shorter search: where none but a plan losing a race exists, a whole
        budget spent showing it at every request would be most of a run (and the symbolic member, which knows
        no learnt race, is left out)."""
        if not learnt:
            return self.core.solve(request)
        budget = self.core.budget
        budget = dataclasses.replace(budget, first_expansions=max(1, budget.first_expansions // LEARNT_SEARCH_SHARE),
                                     symbolic_layers=0)
        result, note = solve_goals(self.core.planner, request, budget)
        if note is not None:
            self.core.events.log.emit(note)
        return result

    def _estimate(self) -> None:
        """The predicted finish and the bound of the plan just taken (what is left of it, from now)."""
        progress = self.core.progress
        if progress is None:
            return
        compiled = self.core.compiled
        durations = step_seconds(compiled, progress.plan, self.seconds)
        self.cycle.planned(self.core.clock(), predicted_finish(progress.ordering, durations),
                           lower_bound(compiled, progress.plan, progress.ordering,
                                       step_seconds(compiled, progress.plan, self.shortest)))

    def _count_effects(self) -> None:
        """The effects of the plan under way seen happen, each counted once as work of its resource."""
        progress = self.core.progress
        if progress is None:
            return
        if progress is not self._counted_plan:
            self._counted_plan, self._counted_steps = progress, set()
            self._step_seconds = step_seconds(self.core.compiled, progress.plan, self.shortest)
        for j in progress.done - self._counted_steps:
            t = progress.transitions[j]
            if t.kind is TransitionKind.EFFECT:
                self.cycle.effect_done(effect_owner(t.source), self._step_seconds[j])
        self._counted_steps |= progress.done

    def cycle_report(self, *, final: bool = False) -> CycleReport:
        """Cycle time so far, the bound, and each resource's idle time with what it waited for; `final`: the run
        is done, and the bound takes in the specifications' exclusions."""
        return self.cycle.report(self.core.clock(), final=final)

    # --- the end ------------------------------------------------------------------------
    def finish(self, outcome: RunOutcome, note: str = "") -> None:
        self.recorder.finish(outcome, note)
