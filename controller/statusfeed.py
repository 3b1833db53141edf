"""What the controller publishes on `{station}/ctl/status`, and the queryables behind it.

A status used to carry every step of the plan with its guard, every resource's health and the last
events, four times a second: 16 kB on average and 41 kB at most on the reference station, 63 kB/s to
every console. Now:

* `PlanBook` gives each plan the controller adopts an id. A status carries the id and a bit per done
  step; `{station}/ctl/plan/{id}` answers the steps with their guards, and for the plan under way what
  each pending step waits for now (worked out only when someone asks).
* `StatusDiet` sends what changed since the previous status (operations, health as a console shows it,
  the plan's id or done steps, new events), and every FULL_EVERY_S the whole picture, so that a reader
  that missed a delta, or a recording, has a full one soon. A query on `{station}/ctl/status` answers the
  last picture published at once: a console that connects late asks it and follows the deltas from there.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable

import msgspec

from common.bus.protocol import Bus, Request
from common.model.compiled import CompiledModel, State
from common.wire.ctl import (
    PlanDetails,
    PlanInfo,
    PlanStepInfo,
    ResourceHealthInfo,
    StatusMessage,
    done_mask,
)
from common.wire.keys import Keys
from common.wire.messages import encode

from .control import ControlCore
from .events import EventLog
from .planner import Plan, PlanStep

FULL_EVERY_S = 5.0  # a full status at least this often: ~7 kB on the reference station
KEEP_PLANS = 32  # plans the plan queryable still answers after they were dropped
NO_PLAN = PlanInfo(0)


class PlanBook:
    """The plans the controller adopted, by id, and their details on request."""

    def __init__(self, compiled: CompiledModel, core: ControlCore) -> None:
        self.compiled = compiled
        self.core = core
        self._plans: OrderedDict[int, tuple[Plan, frozenset[int]]] = OrderedDict()  # id -> plan, done when seen
        self._current: tuple[Plan, int] | None = None
        self._own_guards: dict[str, Callable[[State], bool]] = {}

    def info(self) -> PlanInfo:
        """The plan under way as a status carries it; a plan seen for the first time gets the next id."""
        progress = self.core.progress
        if progress is None:
            return NO_PLAN
        plan = progress.plan
        if self._current is None or self._current[0] is not plan:
            plan_id = self._current[1] + 1 if self._current is not None else 1
            self._current = (plan, plan_id)
            while len(self._plans) >= KEEP_PLANS:
                self._plans.popitem(last=False)
        plan_id = self._current[1]
        self._plans[plan_id] = (plan, frozenset(progress.done))
        return PlanInfo(plan_id, list(plan.goals), len(plan.steps), done_mask(progress.done, len(plan.steps)))

    def details(self, plan_id: int) -> PlanDetails | None:
        known = self._plans.get(plan_id)
        if known is None:
            return None
        plan, done = known
        progress = self.core.progress
        current = progress is not None and progress.plan is plan
        if progress is not None and current:
            done = frozenset(progress.done)
        steps = [PlanStepInfo(step.transition.split(".", 1)[0], step.transition, step.kind.value,
                              step.guard if j in done or not current else self._waits_for(step), j in done)
                 for j, step in enumerate(plan.steps)]
        return PlanDetails(id=plan_id, goals=list(plan.goals), steps=steps, current=current)

    def _waits_for(self, step: PlanStep) -> str:
        """What a pending step waits for: its own guard, or the specifications whose synthesized guard
        holds it back although its own guard holds (the full synthesized guard is `hubctl plan --guards`)."""
        t = self.compiled.by_name[step.transition]
        state = self.core.state
        if step.held_by and t.guard(state) is False and self._own_guard(t.name)(state):
            return f"held back by specification {', '.join(step.held_by)}"
        return step.guard

    def _own_guard(self, name: str) -> Callable[[State], bool]:
        test = self._own_guards.get(name)
        if test is None:
            test = self._own_guards[name] = self.compiled.predicate(self.compiled.by_name[name].source.guard)
        return test


def shown_health(h: ResourceHealthInfo) -> tuple[object, ...]:
    """A health entry as a console shows it: the state's age in whole seconds, and "fresh" below one."""
    age = None if h.age is None else "fresh" if h.age < 1.0 else math.floor(h.age)
    return (h.hub, h.healthy, h.reason, age, h.mirror_lag, h.note)


class StatusDiet:
    """Full pictures (`StatusMessage`s with everything) in, the statuses to publish out."""

    def __init__(self, full_every_s: float = FULL_EVERY_S) -> None:
        self.full_every_s = full_every_s
        self.seq = 0
        self.last_full: StatusMessage | None = None  # the picture of the last status published, as a full one
        self._events_sent = 0
        self._full_at = -math.inf

    def next(self, picture: StatusMessage, log: EventLog, now: float) -> StatusMessage:
        """The status to publish for `picture` (built with the last EVENT_WINDOW events of `log`)."""
        self.seq += 1
        previous = self.last_full
        self.last_full = msgspec.structs.replace(picture, seq=self.seq, full=True, events_total=log.total)
        news = log.since(self._events_sent)  # a delta carries what is new and still held
        new_events = news.events
        self._events_sent = news.cursor
        if previous is None or now - self._full_at >= self.full_every_s:
            self._full_at = now
            return self.last_full
        operations = {op.name: op for op in previous.operations}
        health = {h.resource: shown_health(h) for h in previous.health}
        plan, before = picture.plan or NO_PLAN, previous.plan or NO_PLAN
        same_plan = (plan.id, plan.goals, plan.steps) == (before.id, before.goals, before.steps)
        return msgspec.structs.replace(
            self.last_full, full=False,
            operations=[op for op in picture.operations if operations.get(op.name) != op],
            health=[h for h in picture.health if health.get(h.resource) != shown_health(h)],
            plan=None if same_plan else plan,
            plan_done=plan.done if same_plan and plan.done != before.done else None,
            events=new_events)

    def serve(self, bus: Bus, keys: Keys, plans: PlanBook) -> None:
        """Answer `{station}/ctl/status` with the last picture, `{station}/ctl/plan/{id}` with a plan's details."""

        async def status(_request: Request) -> bytes | None:
            return None if self.last_full is None else encode(self.last_full)

        async def plan(request: Request) -> bytes | None:
            plan_id = keys.plan_of(request.key)
            details = None if plan_id is None else plans.details(plan_id)
            return None if details is None else encode(details)

        bus.declare_queryable(keys.ctl("status"), status)
        bus.declare_queryable(keys.all_plans, plan)
