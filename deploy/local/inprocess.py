"""Run a whole station in one process against its model's own effects (emulated devices).

Time is virtual by default (the run is as fast as planning allows); `realtime=True`
sleeps through the emulated delays as a live station would.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from common.ctl import NoPlanFound, PlanFound
from common.model import Model, OperationState
from controller.planner import Budget
from controller.planner.policy import VIRTUAL_BUDGET
from controller.recorder import RunRecorder, Sink
from controller.stack import build_controller_stack
from hubs.emulator import EffectEmulator


@dataclass
class RunSummary:
    finished: bool
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
    log: list[str] = field(default_factory=list)  # the event log, as text


Reporter = Callable[[str], None]
MAX_TICKS_AT_ONCE = 100  # ticks at one instant of virtual time before the devices get their turn


def run_in_process(
    model: Model,
    *,
    speed: float = 1.0,
    seed: int = 0,
    failure: Mapping[str, float] | None = None,
    realtime: bool = False,
    time_limit: float = 3600.0,
    report: Reporter | None = None,
    budget: Budget = VIRTUAL_BUDGET,
    recording: Sink | None = None,
) -> RunSummary:
    """`recording`: where the run is recorded (controller/recorder.py), closed when it ends."""
    say = report or (lambda _line: None)
    # The model tables are built before the first request, as the controller's planner process does.
    stack = build_controller_stack(model, prepare=True)
    compiled = stack.compiled
    now = 0.0
    core = stack.control_core(lambda: now, budget=budget)
    core.request(*(op.name for op in model.operations))
    recorder = RunRecorder(core, lambda: now, recording)
    recorder.requested(core.requested)
    emulator = EffectEmulator(model, (r.name for r in model.resources), speed=speed, seed=seed, failure=failure)
    deliberate = {t.name for t in compiled.deliberate}
    total = len(model.operations)
    start_wall = time.perf_counter()
    planning = 0.0
    reason = ""
    quiet_ticks = 0
    while True:
        progress_before, state_before = core.progress, core.state
        result = core.tick()
        recorder.ticked()
        recorder.send_changed()
        for name in result.started:
            say(f"{now:7.1f}s  start  {name}")
        for name in result.fired:
            if name in deliberate:
                say(f"{now:7.1f}s    {name}")
        for name in result.finished:
            done = sum(1 for op in model.operations if core.op_state(op.name) is OperationState.FINISHED)
            say(f"{now:7.1f}s  done   {name}  [{done}/{total}]")
        if core.all_finished():
            break
        # A tick that changed anything (a step fired, a plan kept from a new state) may enable the next
        # step at once: tick again before time moves on, as the live controller's next tick would.
        if (core.progress is not progress_before or core.state != state_before) and quiet_ticks < MAX_TICKS_AT_ONCE:
            quiet_ticks += 1
            continue
        quiet_ticks = 0
        request = core.plan_request()
        if request is not None:
            recorder.plan_request(request)
            began = time.perf_counter()
            answer = core.solve(request)
            planning += time.perf_counter() - began
            said = len(core.events.log)
            recorder.plan(request, answer, taken=core.adopt(request, answer))
            for event in core.events.log[said:]:
                if isinstance(event, NoPlanFound | PlanFound):  # once per goal and reason, not per retry
                    say(f"{now:7.1f}s  {event.text}")
            continue
        changes = emulator.step(compiled.unpack(core.state), now)
        if changes:
            recorder.ingested(core.ingest(changes))
            continue
        due = emulator.next_due()
        retry = core.next_retry()
        if retry is not None and retry > now:
            due = retry if due is None else min(due, retry)  # a goal without a plan is tried again then
        if due is None:
            waiting = [n for n in core.executing()]
            reason = f"stuck: nothing can happen; executing: {', '.join(waiting) or 'none'}"
            for event in core.events.log[-5:]:
                say(f"  {event.text}")
            break
        if due - now > 0 and realtime:
            time.sleep(due - now)
        now = max(now, due)
        if now > time_limit:
            reason = f"time limit of {time_limit} emulated seconds reached"
            break
    events = core.events
    recorder.finish("finished" if core.all_finished() else "stuck" if reason.startswith("stuck") else "stopped",
                    reason)
    return RunSummary(
        finished=core.all_finished(),
        operations_finished=sum(1 for op in model.operations if core.op_state(op.name) is OperationState.FINISHED),
        operations_total=total,
        abilities=events.abilities_started,
        plans=events.plans,
        replans=events.replans,
        no_plans=events.no_plans,
        emulated_seconds=now,
        wall_seconds=time.perf_counter() - start_wall,
        planning_seconds=planning,
        reason=reason,
        log=[event.text for event in events.log],
    )
