"""Run a whole station in one process against its model's own effects (emulated devices).

A thin shell around the controller's own loop (controller/loop.py), with an effect emulator for the
hubs: tick, plan (here and now, by counts), let the devices' effects fall due, and move virtual time on
to the next one. Time is virtual by default (the run is as fast as planning allows); `realtime=True`
sleeps through the emulated delays as a live station would. Each device's `delay` of hubs.toml applies
as it does to `hubctl up`'s emulated hubs. With a `ProductionPlan` the station runs its orders, one
product after another, from an order book in memory on the virtual clock, until none is left.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from common.config.hubs_toml import StationConfig
from common.config.modes import DEFAULT_EXECUTION, Execution
from common.config.production import ProductionPlan
from common.model import Duration, Model, OperationState
from common.model.durations import as_duration
from common.resources import durations_of
from common.wire.ctl import NoPlanFound, PlanFound
from controller.cycle import CycleReport, effect_seconds, shortest_seconds
from controller.loop import ControlLoop
from controller.planner import Budget
from controller.planner.policy import VIRTUAL_BUDGET
from controller.production.book import OrderBook
from controller.production.flow import OrderFlow
from controller.production.throughput import OrderThroughput, RunThroughput, summary_lines
from controller.recording.hooks import RunRecorder, Sink, VirtualClock
from controller.recording.schema import RunOutcome
from controller.stack import build_controller_stack
from controller.state import StateStore
from hubs.emulator import EffectEmulator

Reporter = Callable[[str], None]
MAX_TICKS_AT_ONCE = 100  # ticks at one instant of virtual time before the devices get their turn
STUCK_EVENTS_SHOWN = 5


@dataclass
class RunSummary:
    outcome: RunOutcome
    operations_finished: int
    operations_total: int
    abilities: int
    plans: int
    replans: int
    no_plans: int
    emulated_seconds: float
    wall_seconds: float
    planning_seconds: float
    reason: str = ""
    cycle: CycleReport | None = None  # cycle time, the bound, each resource's idle time
    log: list[str] = field(default_factory=list)  # the event log (its newest entries), as text
    orders: list[OrderThroughput] = field(default_factory=list)  # the newest orders finished (flow.RECENT_FIGURES)
    throughput: RunThroughput | None = None  # engines per hour and cycle times, when running orders

    @property
    def finished(self) -> bool:
        return self.outcome is RunOutcome.FINISHED


def emulated_delays(config: StationConfig) -> dict[str, Duration]:
    """Each device's `delay` in hubs.toml (seconds an effect takes at speed 1, or an interval), where it gives one."""
    return config.delays


def run_in_process(
    model: Model,
    *,
    speed: float = 1.0,
    seed: int = 0,
    failure: Mapping[str, float] | None = None,
    delays: Mapping[str, Duration | float] | None = None,
    realtime: bool = False,
    time_limit: float = 3600.0,
    report: Reporter | None = None,
    budget: Budget = VIRTUAL_BUDGET,
    recording: Sink | None = None,
    execution: Execution = DEFAULT_EXECUTION,
    production: ProductionPlan | None = None,
) -> RunSummary:
    """`delays`: seconds an effect of each resource takes at speed 1 (hubs.toml's `delay`; the device
    type's default elsewhere); `time_limit`: emulated seconds; `recording`: where the run is recorded
    (controller/recording/hooks.py), closed when it ends; `production`: the orders to run, one product after
    another (None: every operation once)."""
    say = report or (lambda _line: None)
    # The model tables are built before the first request, as the controller's planner process does.
    stack = build_controller_stack(model, prepare=True)
    compiled = stack.compiled
    clock = VirtualClock()
    core = stack.control_core(clock, budget=budget, execution=execution)
    table = durations_of(model, {r: as_duration(d) for r, d in (delays or {}).items()})
    loop = ControlLoop(core, RunRecorder(core, clock, recording), (r.name for r in model.resources), clock,
                       effect_seconds(model, delays), table.keyed(), shortest_seconds(model, delays))
    flow = None
    if production is None:
        loop.request([op.name for op in model.operations])
    else:
        flow = OrderFlow(OrderBook(StateStore(":memory:"), model, clock))
        flow.queue(production)
        loop.run_orders(flow)
    emulator = EffectEmulator(model, (r.name for r in model.resources), speed=speed, seed=seed, failure=failure,
                              delays=delays)
    deliberate = {t.name for t in compiled.deliberate}
    total = len(model.operations)
    start_wall = time.perf_counter()
    planning = 0.0
    reason = ""
    outcome = RunOutcome.FINISHED
    quiet_ticks = 0
    while True:
        now = clock.now
        progress_before, state_before = core.progress, core.state
        ticked = loop.tick()
        result = ticked.result
        for name in result.started:
            say(f"{now:7.1f}s  start  {name}")
        for name in result.fired:
            if name in deliberate:
                say(f"{now:7.1f}s    {name}")
        for name in result.finished:
            done = sum(1 for op in model.operations if core.op_state(op.name) is OperationState.FINISHED)
            say(f"{now:7.1f}s  done   {name}  [{done}/{total}]")
        for order_event in ticked.orders:
            say(f"{now:7.1f}s  {order_event.text}")
        if loop.orders_done() if flow is not None else core.all_finished():
            break
        # A tick that changed anything (a step fired, a plan kept from a new state) may enable the next
        # step at once: tick again before time moves on, as the live controller's next tick would.
        if (core.progress is not progress_before or core.state != state_before) and quiet_ticks < MAX_TICKS_AT_ONCE:
            quiet_ticks += 1
            continue
        quiet_ticks = 0
        request = loop.plan_request()
        if request is not None:
            began = time.perf_counter()
            adopted = loop.solve(request)
            planning += time.perf_counter() - began
            for event in adopted.events:
                if isinstance(event, NoPlanFound | PlanFound):  # once per goal and reason, not per retry
                    say(f"{now:7.1f}s  {event.text}")
            continue
        changes = emulator.step(compiled.unpack(core.state), now)
        if changes:
            loop.ingest(changes)
            continue
        due = emulator.next_due()
        retry = core.next_retry()
        if retry is not None and retry > now:
            due = retry if due is None else min(due, retry)  # a goal without a plan is tried again then
        if due is None:
            outcome = RunOutcome.STUCK
            reason = f"stuck: nothing can happen; executing: {', '.join(core.executing()) or 'none'}"
            for event in core.events.log.recent(STUCK_EVENTS_SHOWN):
                say(f"  {event.text}")
            break
        if due - now > 0 and realtime:
            time.sleep(due - now)
        clock.now = max(now, due)
        if clock.now > time_limit:
            outcome = RunOutcome.TIME_LIMIT
            reason = f"time limit of {time_limit} emulated seconds reached"
            break
    loop.finish(outcome, reason)
    cycle = loop.cycle_report(final=True)
    for line in cycle.lines():
        say(line)
    throughput = None if flow is None else flow.run_figures()
    if throughput is not None:
        for line in summary_lines(throughput):
            say(line)
    events = core.events
    return RunSummary(
        outcome=outcome,
        operations_finished=sum(1 for op in model.operations if core.op_state(op.name) is OperationState.FINISHED),
        operations_total=total,
        abilities=events.abilities_started,
        plans=events.plans,
        replans=events.replans,
        no_plans=events.no_plans,
        emulated_seconds=clock.now,
        wall_seconds=time.perf_counter() - start_wall,
        planning_seconds=planning,
        reason=reason,
        cycle=cycle,
        log=[event.text for event in events.log],
        orders=[] if flow is None else list(flow.finished),
        throughput=throughput,
    )
