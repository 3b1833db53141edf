"""Replay a recorded run (common/recording) on a fresh control loop (controller/loop.py, the one the live
controller and the in-process runner drive) in virtual time and compare decisions.

The inputs, in the recorded order and at the recorded times (the core's clock is set to each record's
`t`): the values loaded, the resources held, the measured values the controller took, the watchdog's verdicts
(which resources were disabled at each tick), the ticks, the console requests, and when plans were asked
for and answered. The decisions compared one to one: each command sent (values and seq), each operation
transition, each plan request (goals, cause, disabled resources, the hash of the state planned from),
each plan answer and whether it was taken, and the core's event log (replans, plans kept or shortened,
goals without a plan, answered requests). The first record that differs is the divergence.

Plans: an `up --in-process` run plans by counts only (its budget is in the recording), so the replay
plans again with that budget and the plans themselves are compared. A live controller's planner races
against the wall clock (the first answer within seconds, a shortest plan if A* is warm within 150 ms,
improvements streamed while the station goes on): the same search bounded by the recorded expansions
would still differ in which answer arrived when. So a live run's plans are inputs, like the measured
states, rebuilt from their recorded steps on the replayed start state; what the controller made of
them (adopted or dropped, shorter plan taken or not, every command and transition that followed) is
checked. The watchdog's verdicts are inputs too: they follow from when each 50 Hz state arrived, and
the recording keeps what changed, not every arrival. So are the values loaded (persisted ones at
start, mirrors) and the resources held until their mirror comes (controller/command_hold.py).
"""

from __future__ import annotations

import dataclasses
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import msgspec

from common.config.modes import Execution
from common.model import Model
from common.model.compiled import CompiledModel
from common.resources import durations_of
from common.stations import load_model
from common.wire.ctl import OrderFinished
from controller.control import ControlCore, PlanRequest
from controller.loop import ControlLoop
from controller.planner import Budget, NoPlan, Plan, PlanStats
from controller.planner.validate import plan_from_moves
from controller.recording.hooks import RunRecorder, VirtualClock
from controller.recording.reader import Record, Run
from controller.recording.schema import (
    CommandRecord,
    HoldRecord,
    OperationRecord,
    PlanAnswer,
    PlanRecord,
    PlanRequestRecord,
    RecordKind,
    RequestRecord,
    RestoreRecord,
    RunMode,
    RunOutcome,
    StateRecord,
    WatchdogRecord,
    WatchdogVerdict,
    station_model_hash,
)
from controller.stack import build_controller_stack
from controller.timed_check import Verdict

from .orders import ORDER_EVENTS, RECORDS_READ, replay_flow

DECISIONS = frozenset({RecordKind.COMMAND, RecordKind.OPERATION, RecordKind.PLAN_REQUEST, RecordKind.PLAN,
                       RecordKind.EVENT})
# The event log's entries the core decides; the others are the service's notes (hub alive, mirrors missing).
CORE_EVENTS = frozenset({"replan", "plan_kept", "shorter_plan", "faster_plan", "no_plan", "plan_found", "request",
                         "forbidden_state", "forbidden_state_cleared", *ORDER_EVENTS})
# The engine's own order of a run recorded before `[controller] execution` existed (RunMeta.execution None).
EXECUTION_BEFORE_THE_SETTING = Execution.TRACE


class ReplayError(ValueError):
    """A recording that cannot be replayed (names the file and why)."""


@dataclass(frozen=True)
class Divergence:
    t: float
    kind: str
    key: str
    recorded: str
    replayed: str

    def __str__(self) -> str:
        return (f"first diverging event at t={self.t:.3f} s: {self.kind} {self.key}\n"
                f"  recorded: {self.recorded}\n  replayed: {self.replayed}")


@dataclass
class ReplayResult:
    records: int = 0
    decisions: dict[str, int] = field(default_factory=dict)  # compared, by kind
    divergence: Divergence | None = None
    cut_short: int = 0  # decisions replayed after the end of a recording whose controller was killed

    @property
    def same(self) -> bool:
        return self.divergence is None


class ListSink:
    def __init__(self) -> None:
        self.records: list[Record] = []
        self.loaded: list[RestoreRecord] = []  # the values the replayed loop loaded, in order

    def put(self, t: float, kind: RecordKind, key: str, data: Any) -> None:
        if kind in DECISIONS:
            self.records.append(Record(t, kind, key, data))
        elif isinstance(data, RestoreRecord):
            self.loaded.append(data)

    def ingested(self, t: float, changed: dict[str, Any], hub_states: Any) -> None:
        pass  # an input, not a decision

    def update_meta(self, **fields: Any) -> None:
        pass

    def close(self) -> None:
        pass


def is_decision(record: Record) -> bool:
    return record.kind in DECISIONS and (record.kind is not RecordKind.EVENT or record.key in CORE_EVENTS)


def compared(record: Record) -> tuple[Any, ...]:
    """What must be the same in a recorded and a replayed decision."""
    data = record.data
    if isinstance(data, OrderFinished):  # not its cycle: live, the order book times it on the wall clock
        return record.kind, record.key, data.order, data.product_id, data.variant
    if isinstance(data, PlanRecord):  # not the planner's wall time, member or counts
        plan = (data.answer, data.taken, data.goals, data.found, data.steps, data.no_plan, data.unreachable,
                data.proven, data.reason, data.detail)
        return record.kind, record.key, msgspec.to_builtins(plan)
    return record.kind, record.key, msgspec.to_builtins(data)


class Replayer:
    def __init__(self, run: Run, model: Model | None = None) -> None:
        meta = run.meta
        if meta.dropped:
            raise ReplayError(f"{run.parts[0]}: {meta.dropped} records were dropped while recording (the disk "
                              f"did not keep up): the run cannot be replayed")
        if run.first_part != 1:
            raise ReplayError(f"{run.parts[0]}: the run's first part file was deleted ([controller.recording] "
                              f"keep): a replay needs the run from its start")
        self.model = model or load_model(meta.model)
        if station_model_hash(self.model) != meta.model_hash:
            raise ReplayError(f"{run.parts[0]}: recorded with another version of model {meta.model} "
                              f"(hash {meta.model_hash}, now {station_model_hash(self.model)})")
        self.run = run
        self.replans = meta.mode == RunMode.IN_PROCESS and meta.budget is not None  # plans by counts: plan again
        budget = Budget(**meta.budget) if meta.budget else None
        stack = build_controller_stack(self.model, prepare=self.replans)
        self.compiled = stack.compiled
        self.clock = VirtualClock()
        # A plan runs in the order its record names, else in the engine's own, the run's.
        self.core: ControlCore = stack.control_core(self.clock, budget=budget,
                                                    execution=meta.execution or EXECUTION_BEFORE_THE_SETTING)
        self.sink = ListSink()
        # The live controller commands the resources of its hubs.toml: those the recording saw commanded are
        # a subset of the model's, and a resource nobody commands has no command to compare.
        # A run in process checked its plans in time (controller/timed_check.py) against the model's durations.
        durations = (durations_of(self.model).keyed()
                     if meta.mode == RunMode.IN_PROCESS else None)
        self.loop = ControlLoop(self.core, RunRecorder(self.core, self.clock, self.sink),
                                (r.name for r in self.model.resources), self.clock, durations=durations)
        self.loop.request(meta.requested)
        self.loop.run_orders(replay_flow(self.model, self.clock, run.events(kinds=RECORDS_READ)))
        # The values the replayed loop loaded itself as it finished and started orders: their recorded
        # `restore` records are its decisions' traces, not inputs to apply again.
        self.own_loads: deque[RestoreRecord] = deque()
        self.requests = self.loop.requests()
        self.unhealthy: dict[str, str] = {}
        self.held: frozenset[str] = frozenset()  # resources held until their mirror comes (controller/command_hold.py)
        self.asked: dict[int, PlanRequest] = {}
        self._apply: dict[RecordKind, Callable[[Record], None]] = {
            RecordKind.STATE: self._state, RecordKind.WATCHDOG: self._watchdog, RecordKind.TICK: self._tick,
            RecordKind.RESTORE: self._restore, RecordKind.HOLD: self._hold, RecordKind.REQUEST: self._request,
            RecordKind.COMMAND: self._command,
            RecordKind.PLAN_REQUEST: self._plan_request, RecordKind.PLAN: self._plan,
        }

    def replay(self) -> ReplayResult:
        result = ReplayResult()
        recorded: list[Record] = []
        last_t = 0.0
        for record in self.run.events():
            result.records += 1
            last_t = record.t
            if is_decision(record):
                recorded.append(record)
            apply = self._apply.get(record.kind)
            if apply is None:
                continue
            self.clock.now = record.t
            try:
                apply(record)
            except Exception as exc:  # a recorded input the replayed core cannot take: the runs differ here
                result.divergence = Divergence(record.t, record.kind.value, record.key, _show(record.data),
                                               f"cannot be applied: {type(exc).__name__}: {exc}")
                return result
        replayed = [r for r in self.sink.records if is_decision(r)]
        for mine, theirs in zip(recorded, replayed, strict=False):
            if compared(mine) != compared(theirs):
                result.divergence = Divergence(mine.t, mine.kind.value, mine.key, _show(mine.data), _show(theirs.data)
                                               + ("" if theirs.kind is mine.kind and theirs.key == mine.key
                                                  else f" ({theirs.kind.value} {theirs.key} at t={theirs.t:.3f} s)"))
                return result
            result.decisions[mine.kind.value] = result.decisions.get(mine.kind.value, 0) + 1
        if len(replayed) > len(recorded) and self.run.meta.outcome == RunOutcome.RUNNING and \
                all(r.t >= last_t for r in replayed[len(recorded):]):
            # A killed controller's last batch of records (a fraction of a second) never reached the disk.
            result.cut_short = len(replayed) - len(recorded)
        elif len(recorded) != len(replayed):
            extra = (recorded if len(recorded) > len(replayed) else replayed)[min(len(recorded), len(replayed))]
            recorded_text = _show(extra.data) if len(recorded) > len(replayed) else "nothing"
            replayed_text = "nothing" if len(recorded) > len(replayed) else _show(extra.data)
            result.divergence = Divergence(extra.t, extra.kind.value, extra.key, recorded_text, replayed_text)
        return result

    # --- the inputs -----------------------------------------------------------------------
    def _state(self, record: Record) -> None:
        data = record.data_as(StateRecord)
        self.loop.ingest(data.values)

    def _watchdog(self, record: Record) -> None:
        data = record.data_as(WatchdogRecord)
        if data.verdict == WatchdogVerdict.UNHEALTHY:
            self.unhealthy[record.key] = data.detail
        else:
            self.unhealthy.pop(record.key, None)

    def _tick(self, _record: Record) -> None:
        loaded = len(self.sink.loaded)
        if self.loop.tick(self.unhealthy, self.held).orders:
            self.own_loads.extend(self.sink.loaded[loaded:])

    def _command(self, record: Record) -> None:
        # The controller also sends at its command rate, between ticks: a value that changed since the last
        # tick (a mirror taken, a force) goes out then. Here is such a moment: what would it send?
        self.loop.resend(self.held, [record.key])

    def _hold(self, record: Record) -> None:
        data = record.data_as(HoldRecord)
        self.held = frozenset(data.resources)
        self.core.set_unknown(data.paths)

    def _restore(self, record: Record) -> None:
        data = record.data_as(RestoreRecord)
        if self.own_loads and self.own_loads[0].values == data.values:
            self.own_loads.popleft()
            return
        self.core.load(data.values)

    def _request(self, record: Record) -> None:
        data = record.data_as(RequestRecord)
        self.requests.apply(data.request)

    def _plan_request(self, _record: Record) -> None:
        request = self.loop.plan_request()
        if request is not None:
            self.asked[request.generation] = request

    def _plan(self, record: Record) -> None:
        data = record.data_as(PlanRecord)
        request = self.asked.get(data.generation)
        if request is None:
            return  # not asked for in the replay: the plan requests already differ
        if data.answer == PlanAnswer.CHECKED:  # the live controller's verdict on its first plan
            checked = recorded_answer(self.compiled, request, data)
            assert isinstance(checked, Plan)
            self.loop.checked(request, Verdict(checked, (), passed=True))
        elif data.answer == PlanAnswer.IMPROVEMENT:
            answer = recorded_answer(self.compiled, request, data)
            assert isinstance(answer, Plan)
            self.loop.improve(request, answer)
        elif self.replans:
            self.loop.solve(request)
        else:
            self.loop.adopt(request, recorded_answer(self.compiled, request, data))


def recorded_answer(compiled: CompiledModel, request: PlanRequest, data: PlanRecord) -> Plan | NoPlan | None:
    """A recorded plan answer rebuilt for `request`: its steps replayed on the request's start state."""
    stats = PlanStats(data.member, data.ms / 1000, data.expansions, minimal=data.minimal)
    if data.found:
        moves = [(compiled.by_name[s.transition].number, s.outcome) for s in data.steps]
        plan = plan_from_moves(compiled, request.start, moves, tuple(data.goals), stats)
        return dataclasses.replace(plan, execution=Execution(data.execution)) if data.execution else plan
    if not request.goals:
        return None
    return NoPlan(data.no_plan, tuple(data.unreachable), stats, data.proven)


def _show(data: Any) -> str:
    if isinstance(data, CommandRecord):
        return f"{data.values} seq {data.seq}"
    if isinstance(data, OperationRecord):
        return f"{data.before} -> {data.after}"
    if isinstance(data, PlanRequestRecord):
        cause = data.reason + (f": {data.detail}" if data.detail else "")
        return (f"goals {', '.join(data.goals) or '(none)'}; cause {cause}"
                f"; disabled {', '.join(data.disabled) or 'none'}; start state {data.start}")
    if isinstance(data, PlanRecord):
        what = f"{len(data.steps)} steps: " + ", ".join(s.transition for s in data.steps[:6]) + \
            (" ..." if len(data.steps) > 6 else "") if data.found else f"no plan: {data.no_plan}"
        return f"{data.answer} answer, {'taken' if data.taken else 'not taken'}; {what}"
    text = getattr(data, "text", None)
    return text if isinstance(text, str) else repr(data)
