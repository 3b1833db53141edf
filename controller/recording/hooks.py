"""The controller's hooks into its run recording (common/recording): what it took in and what it decided.

One `RunRecorder` per run, called by the control loop (controller/loop.py) that the controller service, the
in-process runner and `hubctl replay` drive, so at the same points in each: a replay's records compare one
to one with the recording's. Without a sink (recording off) every hook returns at once.

Its clock is the core's clock: each record's `t` is what the core read at that moment, so that a replay
that sets the core's clock to `t` makes the same time-dependent decisions (retries of goals without a plan).
"""

from __future__ import annotations

import logging
import sqlite3
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from operator import itemgetter
from pathlib import Path
from types import MappingProxyType
from typing import Any, Protocol

import msgspec

from common.config.hubs_toml import RecordingConfig
from common.model import Kind, Model, OperationState, Value
from common.model.compiled import State
from common.wire.ctl import ConsoleReply, ConsoleRequest, PlannedAlone
from controller.control import ControlCore, PlanRequest
from controller.planner import NoPlan, Plan
from controller.recording.schema import (
    CommandRecord,
    HoldRecord,
    HubState,
    LivelinessRecord,
    OperationRecord,
    PlanAnswer,
    PlanRecord,
    PlanRequestRecord,
    RecordKind,
    RequestRecord,
    RestoreRecord,
    RunMeta,
    RunOutcome,
    StepRecord,
    TickRecord,
    WatchdogRecord,
    WatchdogVerdict,
    state_hash,
    station_model_hash,
)
from controller.recording.writer import RecordingWriter, recording_dir

log = logging.getLogger("statehub.recording")

TICK = TickRecord()
ALL_HEALTHY: Mapping[str, str] = MappingProxyType({})


class StepClock:
    """The live controller's clock: seconds since its start, read from the system clock only when a step
    (an ingested batch, a tick) begins, so that the core and the recording see the same value."""

    def __init__(self) -> None:
        self.origin = time.monotonic()
        self.now = 0.0

    def advance(self) -> float:
        self.now = time.monotonic() - self.origin
        return self.now

    def __call__(self) -> float:
        return self.now


class VirtualClock:
    """The clock of a run in virtual time (in-process, replay): it moves only when its runner sets `now`."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


class Sink(Protocol):
    def put(self, t: float, kind: RecordKind, key: str, data: msgspec.Struct) -> None: ...
    def ingested(self, t: float, changed: dict[str, Value], hub_states: Sequence[HubState]) -> None: ...
    def update_meta(self, **fields: Any) -> None: ...
    def close(self) -> None: ...


class RunRecorder:
    def __init__(self, core: ControlCore, clock: Callable[[], float], sink: Sink | None = None) -> None:
        self.core = core
        self.clock = clock
        self.sink = sink
        compiled = core.compiled
        self._operations = tuple(core.op_index)
        # After every tick: a C-level gather of the operations' values (hundreds of them at the capacity station);
        # itemgetter of one index returns a bare value, not a tuple.
        indices = tuple(core.op_index.values())
        self._op_values_of: Callable[[State], tuple[Value, ...]] = itemgetter(*indices) if len(indices) > 1 \
            else lambda state: tuple(state[i] for i in indices)
        self._op_values = self._operation_values(core.state)
        self._events_read = core.events.log.total  # the event log's cursor: what `after` recorded
        self._unhealthy: dict[str, str] = {}
        self._unhealthy_keys: tuple[str, ...] = ()
        self.command_paths = {
            r.name: [(v.path, compiled.index[v.path]) for v in r.variables if v.kind is Kind.COMMAND]
            for r in core.model.resources}
        self.command_paths = {r: paths for r, paths in self.command_paths.items() if paths}
        if sink is not None:
            core.listener = self
            # The engine's own order, whoever opened the recording: a replay runs the plans recorded without one
            # (PlanRecord.execution "") in it.
            sink.update_meta(execution=core.engine.execution)

    @property
    def path(self) -> Path | None:
        """The recording's first file (None: not recording to a file)."""
        return getattr(self.sink, "path", None)

    # --- inputs -------------------------------------------------------------------------
    def loaded(self, values: Mapping[str, Value]) -> None:
        if self.sink is not None and values:
            self.sink.put(self.clock(), RecordKind.RESTORE, "load", RestoreRecord(values=dict(values)))

    def unknown_set(self, paths: list[str]) -> None:
        if self.sink is not None:
            held = sorted({path.split(".", 1)[0] for path in paths})
            self.sink.put(self.clock(), RecordKind.HOLD, "", HoldRecord(resources=held, paths=paths))

    def requested(self, operations: Iterable[str]) -> None:
        """The operations requested at start (persisted, or all): a replay requests them too."""
        if self.sink is not None:
            self.sink.update_meta(requested=list(operations))

    def ingested(self, changed: dict[str, Value], hub_states: Sequence[HubState] = ()) -> None:
        """Measured values the core took that changed, and each sample's status and mirrored seq, handed on
        as they are: the writer process makes the batch's `states` row of them (schema.StatesFilter), so
        that the controller's thread runs no Python per state for its recording."""
        if self.sink is not None and (changed or hub_states):
            self.sink.ingested(self.clock(), changed, hub_states)

    def liveliness(self, hub: str, alive: bool) -> None:
        if self.sink is not None:
            self.sink.put(self.clock(), RecordKind.LIVELINESS, hub, LivelinessRecord(alive=alive))

    def ticked(self, unhealthy: Mapping[str, str] = ALL_HEALTHY) -> None:
        """After a tick: the watchdog's verdicts it ran with (what changed), the tick, and what it decided."""
        sink = self.sink
        if sink is None:
            return
        t = self.clock()
        # The watchdog lists its verdicts in one order, so the same keys in the same order are the same set:
        # with 500 resources unhealthy, 3 us a tick where comparing the sets took 8.
        keys = tuple(unhealthy)
        if keys != self._unhealthy_keys and unhealthy.keys() != self._unhealthy.keys():
            for resource, reason in unhealthy.items():
                if resource not in self._unhealthy:
                    sink.put(t, RecordKind.WATCHDOG, resource,
                             WatchdogRecord(verdict=WatchdogVerdict.UNHEALTHY, detail=reason))
            for resource in self._unhealthy.keys() - unhealthy.keys():
                sink.put(t, RecordKind.WATCHDOG, resource, WatchdogRecord(verdict=WatchdogVerdict.RECOVERED))
            self._unhealthy = dict(unhealthy)
        self._unhealthy_keys = keys
        sink.put(t, RecordKind.TICK, "", TICK)
        self.after()

    def request(self, request: ConsoleRequest, reply: ConsoleReply) -> None:
        if self.sink is not None:
            self.sink.put(self.clock(), RecordKind.REQUEST, request.action,
                          RequestRecord(request=request, accepted=reply.accepted, reason=reply.reason))
            self.after()

    # --- decisions ----------------------------------------------------------------------
    def command(self, resource: str, seq: int) -> None:
        """A changed command of `resource`, as sent with `seq` (its values: the core's state now; the
        outbox, controller/outbox.py, decides which commands changed and their seq)."""
        if self.sink is not None:
            state = self.core.state
            values = {path: state[i] for path, i in self.command_paths[resource]}
            self.sink.put(self.clock(), RecordKind.COMMAND, resource, CommandRecord(values=values, seq=seq))

    def plan_request(self, request: PlanRequest) -> None:
        if self.sink is not None:
            cause = request.reason
            self.sink.put(self.clock(), RecordKind.PLAN_REQUEST, str(request.generation), PlanRequestRecord(
                generation=request.generation, goals=list(request.goals), reason=cause.reason.value,
                detail=cause.detail, disabled=sorted(request.disabled), start=state_hash(request.start)))

    def plan(self, request: PlanRequest, result: Plan | NoPlan | None, *, taken: bool, improvement: bool = False,
             note: PlannedAlone | None = None, checked: bool = False) -> None:
        """An answer to `request`, after the core took it (`taken`) or not; `checked`: the timed check's verdict
        on the first answer, with the order it allows (`taken`: the plan under way runs in it from now on)."""
        if self.sink is None:
            return
        record = plan_record(request, result, taken=taken, improvement=improvement)
        if checked:
            record.answer = PlanAnswer.CHECKED
        if note is not None:
            record.planned_alone = note.operation
        self.sink.put(self.clock(), RecordKind.PLAN, str(request.generation), record)
        self.after()

    def after(self) -> None:
        """Operation transitions and event log entries since the last call."""
        sink = self.sink
        if sink is None:
            return
        state = self.core.state
        values = self._operation_values(state)
        if values != self._op_values:
            t = self.clock()
            for name, old, new in zip(self._operations, self._op_values, values, strict=True):
                if old != new:
                    record = OperationRecord(before=OperationState(str(old)), after=OperationState(str(new)))
                    sink.put(t, RecordKind.OPERATION, name, record)
            self._op_values = values
        events = self.core.events.log
        if events.total != self._events_read:  # after every tick: nothing new is the common case
            news = events.since(self._events_read)
            if news.missed:  # called after every step, far below the log's bound: not expected
                log.error("the run recording missed %d events of the controller's log", news.missed)
            t = self.clock()
            for event in news.events:
                # Its `kind` on the wire: each event class names it (tag="..."), which msgspec types as str | int.
                sink.put(t, RecordKind.EVENT, str(type(event).__struct_config__.tag), event)
            self._events_read = news.cursor

    def _operation_values(self, state: State) -> tuple[Value, ...]:
        return self._op_values_of(state)

    # --- the end ------------------------------------------------------------------------
    def finish(self, outcome: RunOutcome, note: str = "") -> None:
        """Write the run's outcome and counts, and close the recording."""
        sink = self.sink
        if sink is None:
            return
        self.after()
        core = self.core
        events = core.events
        done = sum(1 for name in self._operations if core.op_state(name) is OperationState.FINISHED)
        sink.update_meta(outcome=outcome.recorded, note=note, ended=time.time(), duration=self.clock(),
                         operations_done=done, operations_total=len(self._operations), plans=events.plans,
                         replans=events.replans, faults=events.log.faults)
        sink.close()
        self.sink = None


def plan_record(request: PlanRequest, result: Plan | NoPlan | None, *, taken: bool,
                improvement: bool = False) -> PlanRecord:
    cause = request.reason
    answer = PlanAnswer.IMPROVEMENT if improvement else PlanAnswer.FIRST
    record = PlanRecord(generation=request.generation, answer=answer, taken=taken, goals=list(request.goals),
                        reason=cause.reason.value, detail=cause.detail)
    if isinstance(result, Plan):
        stats = result.stats
        record.goals = list(result.goals)  # one of the request's, when planned alone
        record.steps = [StepRecord(s.transition, s.outcome) for s in result.steps]
        record.ms, record.member = stats.seconds * 1000, stats.method
        record.expansions, record.minimal = stats.expanded, stats.minimal
        record.execution = "" if result.execution is None else result.execution.value
    else:
        record.found = False
        if isinstance(result, NoPlan):
            record.no_plan, record.unreachable, record.proven = result.reason, list(result.unreachable), result.proven
            record.ms, record.member = result.stats.seconds * 1000, result.stats.method
            record.expansions = result.stats.expanded
    return record


def open_recording(settings: RecordingConfig, meta: RunMeta, model: Model) -> RecordingWriter | None:
    """A new run's recording in `settings.dir` (bounded as `[controller.recording]` says); None, said in the
    log, where it cannot be written: the station runs without a recording rather than not at all."""
    meta.model_hash = station_model_hash(model)
    meta.operations_total = len(model.operations)
    meta.started = meta.started or time.time()
    directory = recording_dir(settings.dir)
    try:
        return RecordingWriter(directory, meta, max_bytes=int(settings.max_mb * 1024 * 1024), keep=settings.keep)
    except (OSError, sqlite3.Error) as exc:
        log.error("the run is not recorded: cannot write into %s ([controller.recording] dir): %s", directory, exc)
        return None
