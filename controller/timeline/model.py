"""A recorded run as a Gantt chart's data: spans in lanes, markers, shaded periods (no drawing here).

`build_timeline(run)` reads a recording (controller/recording/reader.py) once, in order:

* one lane per resource with a span per ability, from when its `starting` (or `executing`) phase
  first holds to when its `finished` phase holds ("done"), or to when it left those phases without
  finishing ("aborted"), or to the end of the run ("running"). The phases are the model's predicates,
  evaluated on the commands and measured values the recording holds (estimated variables keep the
  values they were restored with);
* one lane per operation with a span per state it entered (executing, finished, error; initial is
  the absence of a span);
* a marker per plan request (the first plan and every replan) with its reason and what was answered;
* unhealthy periods per resource (the watchdog's verdicts), and faults (the controller's event log
  entries an operator should see) as markers on the timeline.

Times are the recording's `t`: seconds since the run's start on the controller's clock (virtual
time in `up --in-process`). render.py draws a Timeline with matplotlib; the console draws it as text.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from common.model import Model, OperationState, Value
from common.model.compiled import CompiledModel
from common.wire.ctl import Event
from controller.recording.reader import Run
from controller.recording.schema import (
    CommandRecord,
    OperationRecord,
    PlanAnswer,
    PlanRecord,
    PlanRequestRecord,
    RecordKind,
    RestoreRecord,
    StateRecord,
    WatchdogRecord,
    WatchdogVerdict,
)

READ = (RecordKind.RESTORE, RecordKind.STATE, RecordKind.COMMAND, RecordKind.OPERATION, RecordKind.PLAN_REQUEST,
        RecordKind.PLAN, RecordKind.WATCHDOG, RecordKind.EVENT)  # every kind but the ticks
ACTIVE_PHASES = ("starting", "executing")


@dataclass(frozen=True)
class Span:
    lane: str  # a resource, or an operation
    label: str  # the ability (without its resource), or the operation's state
    start: float
    end: float
    outcome: str = ""  # an ability: done, aborted or running; an operation: its state


class MarkerKind(enum.StrEnum):
    """What a marker on the timeline's time axis stands for (the word is shown beside it)."""

    PLAN = "plan"  # the run's first plan request
    REPLAN = "replan"  # every later one
    FAULT = "fault"  # a fault in the controller's event log


@dataclass(frozen=True)
class Marker:
    t: float
    kind: MarkerKind
    text: str
    lane: str = ""  # the resource or operation it is about, if one


@dataclass(frozen=True)
class Period:
    lane: str  # the resource
    start: float
    end: float
    reason: str


@dataclass
class Timeline:
    station: str
    run: str
    end: float  # the run's last t
    resources: list[str] = field(default_factory=list)  # lanes, in the model's order
    operations: list[str] = field(default_factory=list)
    abilities: list[Span] = field(default_factory=list)
    operation_spans: list[Span] = field(default_factory=list)
    plans: list[Marker] = field(default_factory=list)
    faults: list[Marker] = field(default_factory=list)
    unhealthy: list[Period] = field(default_factory=list)
    note: str = ""  # what could not be shown, and why

    @property
    def lanes(self) -> list[str]:
        return self.resources + self.operations


@dataclass
class _Ability:
    name: str  # without the resource
    active: Callable[[Sequence[Value]], bool]
    finished: Callable[[Sequence[Value]], bool]


def _any_of(tests: list[Callable[[Sequence[Value]], bool]]) -> Callable[[Sequence[Value]], bool]:
    return lambda state: any(test(state) for test in tests)


class _Abilities:
    """Each resource's abilities as predicates over a state, and the spans they open and close."""

    def __init__(self, model: Model) -> None:
        self.compiled = CompiledModel(model)
        self.state: list[Value] = list(self.compiled.initial())
        self.by_resource: dict[str, list[_Ability]] = {}
        for resource in model.resources:
            for ability in resource.abilities:
                active = [ability.predicates[p] for p in ACTIVE_PHASES if p in ability.predicates]
                finished = ability.predicates.get("finished")
                if not active or finished is None:
                    continue  # tracking and phase-less abilities have no span
                tests = [self.compiled.predicate(p) for p in active]
                self.by_resource.setdefault(resource.name, []).append(_Ability(
                    ability.name.split(".", 1)[1],
                    _any_of(tests),
                    self.compiled.predicate(finished)))
        self.open: dict[tuple[str, str], float] = {}
        self.spans: list[Span] = []

    def apply(self, values: dict[str, Value]) -> None:
        index = self.compiled.index
        for path, value in values.items():
            i = index.get(path)
            if i is not None:
                self.state[i] = value

    def changed(self, resource: str, t: float) -> None:
        state = self.state
        for ability in self.by_resource.get(resource, ()):
            key = (resource, ability.name)
            began = self.open.get(key)
            if began is None:
                if ability.active(state):
                    self.open[key] = t
            elif ability.finished(state):
                self.spans.append(Span(resource, ability.name, began, t, "done"))
                del self.open[key]
            elif not ability.active(state):
                self.spans.append(Span(resource, ability.name, began, t, "aborted"))
                del self.open[key]

    def close(self, end: float) -> None:
        for (resource, name), began in self.open.items():
            self.spans.append(Span(resource, name, began, end, "running"))
        self.open.clear()


def build_timeline(run: Run, model: Model | None = None) -> Timeline:
    """The timeline of `run`; `model`: the run's model (default: loaded from the recording's meta)."""
    meta = run.meta
    note = ""
    if model is None:
        from common.stations import load_model

        try:
            model = load_model(meta.model)
        except Exception as exc:  # an old recording of a model that moved: the rest is still worth showing
            note = f"no ability spans: the model {meta.model!r} does not load ({type(exc).__name__}: {exc})"
    abilities = _Abilities(model) if model is not None else None
    end = max(run.end_t, meta.duration)
    timeline = Timeline(station=meta.station, run=meta.run, end=end, note=note,
                        resources=[r.name for r in model.resources] if model is not None else [],
                        operations=list(meta.requested) or ([op.name for op in model.operations] if model else []))
    operation_open: dict[str, tuple[str, float]] = {}
    unhealthy_open: dict[str, tuple[float, str]] = {}
    plan_markers: dict[str, int] = {}  # plan id -> index in timeline.plans
    for record in run.events(kinds=READ):
        t, data = record.t, record.data
        if isinstance(data, RestoreRecord | StateRecord | CommandRecord):
            if abilities is not None:
                abilities.apply(data.values)
                if not isinstance(data, RestoreRecord):
                    abilities.changed(record.key, t)
        elif isinstance(data, OperationRecord):
            _operation(timeline, operation_open, record.key, data.after, t)
        elif isinstance(data, PlanRequestRecord):
            kind = MarkerKind.PLAN if not timeline.plans else MarkerKind.REPLAN
            text = data.reason + (f": {data.detail}" if data.detail else "")
            plan_markers[record.key] = len(timeline.plans)
            timeline.plans.append(Marker(t, kind, text))
        elif isinstance(data, PlanRecord):
            _answered(timeline, plan_markers.get(record.key), data)
        elif isinstance(data, WatchdogRecord):
            _health(timeline, unhealthy_open, record.key, data, t)
        elif isinstance(data, Event) and data.fault:
            lane = getattr(data, "resource", "") or getattr(data, "hub", "")
            timeline.faults.append(Marker(t, MarkerKind.FAULT, data.text, lane))
    for name, (state, began) in operation_open.items():
        timeline.operation_spans.append(Span(name, state, began, end, state))
    for resource, (began, reason) in unhealthy_open.items():
        timeline.unhealthy.append(Period(resource, began, end, reason))
    if abilities is not None:
        abilities.close(end)
        timeline.abilities = sorted(abilities.spans, key=lambda s: (s.start, s.lane))
    for name in operation_open:
        if name not in timeline.operations:
            timeline.operations.append(name)
    return timeline


def _operation(timeline: Timeline, open_: dict[str, tuple[str, float]], name: str, state: str, t: float) -> None:
    previous = open_.pop(name, None)
    if previous is not None:
        timeline.operation_spans.append(Span(name, previous[0], previous[1], t, previous[0]))
    if state != OperationState.INITIAL:
        open_[name] = (state, t)


def _answered(timeline: Timeline, at: int | None, data: PlanRecord) -> None:
    """The first answer to a request, said on its marker: how many steps, or why there is none."""
    if at is None or data.answer != PlanAnswer.FIRST:
        return
    marker = timeline.plans[at]
    answer = f"{len(data.steps)} steps ({data.member})" if data.found else f"no plan: {data.no_plan}"
    timeline.plans[at] = Marker(marker.t, marker.kind, f"{marker.text} -> {answer}", marker.lane)


def _health(timeline: Timeline, open_: dict[str, tuple[float, str]], resource: str, data: WatchdogRecord,
            t: float) -> None:
    if data.verdict == WatchdogVerdict.UNHEALTHY:
        open_.setdefault(resource, (t, data.detail))
        return
    began = open_.pop(resource, None)
    if began is not None:
        timeline.unhealthy.append(Period(resource, began[0], t, began[1]))
