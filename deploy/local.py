"""Run a whole station in one process against its model's own effects (emulated devices).

Time is virtual by default (the run is as fast as planning allows); `realtime=True`
sleeps through the emulated delays as a live station would.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from common.model import Model
from common.model.compiled import CompiledModel
from controller.control import ERROR_RETRY_S, ControlCore
from controller.planner import NoPlan, Planner
from controller.synthesis import synthesize
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
    log: list[str] = field(default_factory=list)


Reporter = Callable[[str], None]


def run_in_process(
    model: Model,
    *,
    speed: float = 1.0,
    seed: int = 0,
    failure: Mapping[str, float] | None = None,
    realtime: bool = False,
    time_limit: float = 3600.0,
    report: Reporter | None = None,
) -> RunSummary:
    say = report or (lambda _line: None)
    guards = synthesize(model)
    compiled = CompiledModel(model, guards.guards)
    planner = Planner(compiled, guards.forbidden)
    now = 0.0
    core = ControlCore(compiled, planner, clock=lambda: now)
    core.request(*(op.name for op in model.operations))
    emulator = EffectEmulator(model, (r.name for r in model.resources), speed=speed, seed=seed, failure=failure)
    deliberate = {t.name for t in compiled.deliberate}
    total = len(model.operations)
    start_wall = time.perf_counter()
    planning = 0.0
    reason = ""
    while True:
        result = core.tick()
        for name in result.started:
            say(f"{now:7.1f}s  start  {name}")
        for name in result.fired:
            if name in deliberate:
                say(f"{now:7.1f}s    {name}")
        for name in result.finished:
            done = sum(1 for op in model.operations if core.op_state(op.name) == "finished")
            say(f"{now:7.1f}s  done   {name}  [{done}/{total}]")
        if core.all_finished():
            break
        request = core.plan_request()
        if request is not None:
            began = time.perf_counter()
            answer = core.solve(request)
            planning += time.perf_counter() - began
            core.adopt(request, answer)
            if isinstance(answer, NoPlan):
                say(f"{now:7.1f}s  no plan for {', '.join(answer.unreachable) or 'the goals'}: {answer.reason}")
            continue
        changes = emulator.step(compiled.unpack(core.state), now)
        if changes:
            core.ingest(changes)
            continue
        due = emulator.next_due()
        if due is None and core.errors:
            due = min(since for _, since in core.errors.values()) + ERROR_RETRY_S  # wait for the retry
            if due <= now:
                due = now + ERROR_RETRY_S
        if due is None:
            waiting = [n for n in core.executing()]
            reason = f"stuck: nothing can happen; executing: {', '.join(waiting) or 'none'}"
            for line in core.events.log[-5:]:
                say(f"  {line}")
            break
        if due - now > 0 and realtime:
            time.sleep(due - now)
        now = max(now, due)
        if now > time_limit:
            reason = f"time limit of {time_limit} emulated seconds reached"
            break
    events = core.events
    return RunSummary(
        finished=core.all_finished(),
        operations_finished=sum(1 for op in model.operations if core.op_state(op.name) == "finished"),
        operations_total=total,
        abilities=events.abilities_started,
        plans=events.plans,
        replans=events.replans,
        no_plans=events.no_plans,
        emulated_seconds=now,
        wall_seconds=time.perf_counter() - start_wall,
        planning_seconds=planning,
        reason=reason,
        log=events.log,
    )
