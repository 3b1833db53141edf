"""What the overview page shows, as plain data: pure functions of what the controller published.

`picture(...)` turns the newest full status (controller/console/statusview.py merges the deltas),
the details of the plan under way and what the station's files say (goals, device modes) into a
`Picture`, which the page receives as JSON and draws as it is. `gantt(...)` does the same for the
run's `Timeline` (controller/timeline/model.py, the data of `hubctl timeline`).

Every row carries a `Severity`: the page is grey (ISA-101 high-performance HMI) and colours only
what is abnormal, so what is abnormal is decided here, where it is tested, not in the page.
"""

from __future__ import annotations

import enum
from collections.abc import Iterable

import msgspec

from common.model import OperationState
from common.wire.ctl import Event, PlanDetails, PlanInfo, ProductionInfo, ResourceHealthInfo, StatusMessage
from controller.console.station import StationInfo
from controller.console.view import OperationClock, duration, plan_summary, production_summary
from controller.timeline.model import Timeline

EVENTS_SHOWN = 12
SILENT_AFTER_S = 2.0  # the controller publishes its status every 0.25 s: silence past this is abnormal


class Severity(enum.StrEnum):
    """How a row is drawn: grey, or marked as abnormal."""

    NORMAL = "normal"
    WARNING = "warning"  # not as it should be, the station still works (a mirror behind, a note)
    ALARM = "alarm"  # needs someone: an operation in error, an unhealthy resource, a silent controller


class OperationRow(msgspec.Struct, frozen=True):
    name: str
    state: OperationState
    goal: str
    in_state: str  # `0:07`: since when it is in its state, on the controller's clock
    error: str
    severity: Severity


class PlanStepRow(msgspec.Struct, frozen=True):
    number: int  # from 1
    transition: str
    kind: str
    done: bool
    waits_for: str  # a pending step's guard, what it waits for now; "" once done


class PlanView(msgspec.Struct, frozen=True):
    summary: str  # `3/12 steps for ...`, or `no plan`
    steps: list[PlanStepRow]  # empty until the plan's details came from the controller


class ResourceRow(msgspec.Struct, frozen=True):
    resource: str
    hub: str
    mode: str
    health: str  # `ok`, or the watchdog's reason
    age: str  # of its last state
    mirror: str  # `ok`, or how many commands it is behind
    severity: Severity


class EventRow(msgspec.Struct, frozen=True):
    text: str
    severity: Severity


class Picture(msgspec.Struct, frozen=True):
    station: str
    connected: bool  # a status came, and not too long ago
    headline: str  # the controller and its state, or why there is nothing to show
    severity: Severity  # of the headline
    production: str  # the current order, the queue and the last cycle times ("" when no orders)
    counters: str
    operations: list[OperationRow]
    plan: PlanView
    resources: list[ResourceRow]
    events: list[EventRow]  # newest last
    alarms: int  # rows in alarm, for the page's title


# --- the status ----------------------------------------------------------------------------------

# What a supervisor looks for first: what is wrong, then what is under way; the rest in the model's order.
OPERATION_ORDER = {OperationState.ERROR: 0, OperationState.EXECUTING: 1, OperationState.INITIAL: 2,
                   OperationState.FINISHED: 3}


def operation_rows(status: StatusMessage, info: StationInfo, clock: OperationClock) -> list[OperationRow]:
    rows = []
    for op in status.operations:
        since = clock.since(op, status.uptime)
        severity = Severity.ALARM if op.state == OperationState.ERROR else Severity.NORMAL
        rows.append(OperationRow(op.name, op.state, info.goals.get(op.name, ""), duration(status.uptime - since),
                                 op.error, severity))
    return sorted(rows, key=lambda row: OPERATION_ORDER.get(row.state, len(OPERATION_ORDER)))


def plan_view(plan: PlanInfo | None, details: PlanDetails | None) -> PlanView:
    """The plan under way: its steps once its details (the plan queryable's answer) are of this plan, each
    step done or what it waits for. The steps still to come first (what the station waits for), in plan
    order, then those done."""
    steps = []
    if plan is not None and details is not None and details.id == plan.id:
        for j, step in enumerate(details.steps):
            done = plan.is_done(j)
            steps.append(PlanStepRow(j + 1, step.transition, step.kind, done, "" if done else step.guard))
    return PlanView(plan_summary(plan), sorted(steps, key=lambda step: step.done))


def resource_row(health: ResourceHealthInfo, info: StationInfo) -> ResourceRow:
    if not health.healthy:
        text, severity = health.reason or "unhealthy", Severity.ALARM
    elif health.note:
        text, severity = f"ok ({health.note})", Severity.WARNING
    else:
        text, severity = "ok", Severity.NORMAL
    if health.mirror_lag and severity is Severity.NORMAL:
        severity = Severity.WARNING
    age = "-" if health.age is None else "< 1 s" if health.age < 1.0 else f"{health.age:.1f} s"
    mirror = "ok" if health.mirror_lag == 0 else f"{health.mirror_lag} behind"
    mode = info.modes.get(health.resource)
    return ResourceRow(health.resource, health.hub, str(mode) if mode is not None else "?", text, age, mirror,
                       severity)


def event_rows(events: Iterable[Event]) -> list[EventRow]:
    return [EventRow(e.text, Severity.ALARM if e.fault else Severity.NORMAL) for e in events][-EVENTS_SHOWN:]


def counters(status: StatusMessage) -> str:
    return (f"{status.abilities} abilities started, {status.plans} plans, {status.replans} replans, "
            f"{status.no_plans} goals without a plan")


def headline(status: StatusMessage | None, silent_s: float | None) -> tuple[str, Severity, bool]:
    """What the controller is doing, and whether it is heard: (text, severity, connected)."""
    if status is None:
        return "no status from the controller yet", Severity.ALARM, False
    if silent_s is not None and silent_s > SILENT_AFTER_S:
        return (f"controller {status.controller} silent for {silent_s:.0f} s (last heard at "
                f"{duration(status.uptime)})"), Severity.ALARM, False
    state = "finished" if status.finished else "paused" if status.paused else "running"
    return f"controller {status.controller}: {state}, up {duration(status.uptime)}", Severity.NORMAL, True


def production_text(production: ProductionInfo | None) -> str:
    return production_summary(production)


def picture(station: str, status: StatusMessage | None, details: PlanDetails | None, info: StationInfo,
            clock: OperationClock, events: Iterable[Event], silent_s: float | None) -> Picture:
    """The page's picture of the newest full `status`; `silent_s`: seconds since a status last came."""
    text, severity, connected = headline(status, silent_s)
    if status is None:
        return Picture(station, False, text, severity, "", "", [], PlanView("no plan", []), [], event_rows(events),
                       1)
    operations = operation_rows(status, info, clock)
    resources = [resource_row(h, info) for h in status.health]
    shown_events = event_rows(events)
    alarms = (sum(r.severity is Severity.ALARM for r in operations) + sum(r.severity is Severity.ALARM
                                                                          for r in resources)
              + (severity is Severity.ALARM))
    return Picture(station, connected, text, severity, production_text(status.production), counters(status),
                   operations, plan_view(status.plan, details), resources, shown_events, alarms)


# --- the timeline --------------------------------------------------------------------------------

class GanttSpan(msgspec.Struct, frozen=True, array_like=True):
    """One bar: lane index, label, start and end (seconds since the run began), outcome or state."""

    lane: int
    label: str
    start: float
    end: float
    outcome: str


class GanttMarker(msgspec.Struct, frozen=True, array_like=True):
    t: float
    kind: str  # plan, replan, fault
    text: str
    lane: int  # -1: about no lane


class Gantt(msgspec.Struct, frozen=True):
    run: str  # "" when there is no recorded run to draw
    end: float
    lanes: list[str]
    resources: int  # the first `resources` lanes are resources, the rest operations
    abilities: list[GanttSpan]
    operations: list[GanttSpan]
    unhealthy: list[GanttSpan]  # outcome: the watchdog's reason
    markers: list[GanttMarker]
    note: str


def no_gantt(note: str) -> Gantt:
    return Gantt("", 0.0, [], 0, [], [], [], [], note)


def gantt(timeline: Timeline) -> Gantt:
    """The timeline as the page draws it: lanes by index, times rounded to milliseconds (a smaller document)."""
    lanes = timeline.lanes
    index = {lane: i for i, lane in enumerate(lanes)}

    def spans(items: Iterable[tuple[str, str, float, float, str]]) -> list[GanttSpan]:
        return [GanttSpan(index[lane], label, round(start, 3), round(end, 3), outcome)
                for lane, label, start, end, outcome in items if lane in index]

    markers = [GanttMarker(round(m.t, 3), str(m.kind), m.text, index.get(m.lane, -1))
               for m in (*timeline.plans, *timeline.faults)]
    return Gantt(
        run=timeline.run, end=round(timeline.end, 3), lanes=lanes, resources=len(timeline.resources),
        abilities=spans((s.lane, s.label, s.start, s.end, s.outcome) for s in timeline.abilities),
        operations=spans((s.lane, s.label, s.start, s.end, s.outcome) for s in timeline.operation_spans),
        unhealthy=spans((p.lane, "unhealthy", p.start, p.end, p.reason) for p in timeline.unhealthy),
        markers=sorted(markers, key=lambda m: m.t), note=timeline.note)
