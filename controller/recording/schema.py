"""The layout of a run recording: one SQLite file per run, append-only.

Two tables::

    run_meta(key TEXT PRIMARY KEY, value TEXT)   -- JSON values; the keys are RunMeta's fields
    events(id INTEGER PRIMARY KEY,               -- insertion order: the order the controller acted in
           t REAL,                               -- seconds since the run's start, on the controller's
                                                 -- clock (virtual time in `up --in-process`)
           kind TEXT,                            -- a RecordKind
           key TEXT,                             -- what the record is about (resource, hub, plan, ...)
           data BLOB)                            -- MessagePack of the kind's struct (DATA_TYPES)

indexed by `t` and, once a part file is complete, by `(kind, key, t)`. A run longer than
`[controller.recording] max_mb` goes on in a next part file (`part` 2, 3, ... with the same `run` id);
see reader.py.

What each kind records (key: data):

* `states` ("": StatesRecord): one ingested batch: the measured values the controller took that changed,
  and the hub status and mirrored command seq of each resource whose status changed or whose values did
  (StatesFilter, run by the writer process). One row per batch: at 500 resources x 50 Hz, a row per state
  cost the controller 25 % of its ingest capacity. The reader expands it into one `state` record per
  resource (below).
* `state` (resource: StateRecord): what a reader yields for each resource of a `states` row (format 1
  files and saved replays store these rows themselves).
* `command` (resource: CommandRecord): a command sent with new values (the first one too), with its seq.
* `liveliness` (hub: LivelinessRecord): its token appeared or vanished.
* `watchdog` (resource: WatchdogRecord): the verdict turned unhealthy (with the reason) or recovered.
* `tick` ("": TickRecord): the engine ticked (replay ticks at the same points).
* `restore` ("load": RestoreRecord): values the controller loaded: persisted ones at start, a hub's mirror.
* `hold` ("": HoldRecord): the resources held (their command state unknown until their mirror comes).
* `plan_request` (plan id: PlanRequestRecord): a plan asked for: goals, cause, start state's hash.
* `plan` (plan id: PlanRecord): an answer to that request: steps or why none, member, time, expansions,
  and whether the controller took it.
* `operation` (operation: OperationRecord): an operation's state changed (`from` -> `to`).
* `request` (action: RequestRecord): a console request and the controller's answer.
* `event` (event kind: the `common.wire.ctl` Event as encoded): the controller's event log (replans, faults).

The plan id is the request's generation, as text.
"""

from __future__ import annotations

import enum
import hashlib
from typing import Any, TypedDict

import msgspec

from common.config.modes import Execution
from common.model import Model, OperationState, Value
from common.wire.ctl import ConsoleEvent, ConsoleRequest
from common.wire.messages import HubStatus

FORMAT = 2  # bump on any incompatible change of the tables or of the structs below
READABLE_FORMATS = (1, 2)  # format 1: per-state rows only, which format 2 still reads

DDL = """
CREATE TABLE IF NOT EXISTS run_meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY,
    t REAL NOT NULL,
    kind TEXT NOT NULL,
    key TEXT NOT NULL,
    data BLOB NOT NULL
);
CREATE INDEX IF NOT EXISTS events_t ON events (t);
"""
# Built when a part file is complete: kept up to date while writing, it doubled the cost of an insert.
KIND_KEY_INDEX = "CREATE INDEX IF NOT EXISTS events_kind_key_t ON events (kind, key, t)"

SUFFIX = ".sqlite"


class RecordKind(enum.StrEnum):
    STATE = "state"
    STATES = "states"  # stored only: read as `state` records
    COMMAND = "command"
    LIVELINESS = "liveliness"
    WATCHDOG = "watchdog"
    TICK = "tick"
    RESTORE = "restore"
    HOLD = "hold"
    PLAN_REQUEST = "plan_request"
    PLAN = "plan"
    OPERATION = "operation"
    REQUEST = "request"
    EVENT = "event"


class RunMode(enum.StrEnum):
    """How the recorded run was made."""

    UP = "up"  # `hubctl up`: the station's processes over Zenoh on this machine
    IN_PROCESS = "in-process"  # `hubctl up --in-process`: one process, virtual time, planning by counts
    SERVICE = "service"  # the controller as a service (`hubctl controller`)


class RunOutcome(enum.StrEnum):
    """How the run ended (`RunMeta.outcome`)."""

    FINISHED = "finished"  # every operation done
    STOPPED = "stopped"  # stopped from outside (Ctrl-C, SIGTERM, a time limit)
    STUCK = "stuck"  # no progress possible
    TIME_LIMIT = "time-limit"  # in virtual time: the run's time limit came first
    RUNNING = "running"  # not ended: still running, or its controller was killed before writing its end

    @property
    def recorded(self) -> RunOutcome:
        """As a recording's meta says it (`hubctl runs`): a run ended by its time limit was stopped, its note
        says why."""
        return RunOutcome.STOPPED if self is RunOutcome.TIME_LIMIT else self


class WatchdogVerdict(enum.StrEnum):
    """What a `watchdog` record says of its resource."""

    UNHEALTHY = "unhealthy"  # `detail`: why
    RECOVERED = "recovered"


class PlanAnswer(enum.StrEnum):
    """Which of a request's answers a `plan` record is (the planner is anytime)."""

    FIRST = "first"
    IMPROVEMENT = "improvement"
    CHECKED = "checked"  # the live planner process's timed check of the first plan: `taken` if its order loosened


class BudgetCounts(TypedDict, total=False):
    """The planner counts that bounded an in-process run's search: the `Budget` fields of the same names,
    so that a replay plans alike."""

    first_expansions: int
    improve_expansions: int
    symbolic_layers: int


class RunMeta(msgspec.Struct, kw_only=True):
    """A run's description (`run_meta`); `ended`, `outcome` and the counts are written when it ends
    (`outcome` stays RUNNING in a recording whose controller was killed)."""

    format: int = FORMAT
    run: str = ""  # the run's id, shared by its part files
    part: int = 1
    station: str = ""
    model: str = ""  # module:attribute
    model_hash: str = ""  # station_model_hash: a replay refuses another model
    config: str = ""  # hubs.toml path ("" in-process)
    mode: RunMode = RunMode.SERVICE
    seed: int | None = None  # of emulated outcomes (up, in-process)
    budget: BudgetCounts | None = None  # planner counts when they bound the search (in-process)
    execution: Execution | None = None  # the engine's own order (None: recorded before it could be chosen)
    requested: list[str] = msgspec.field(default_factory=list)  # operations requested at start
    started: float = 0.0  # wall clock (time.time())
    ended: float | None = None
    outcome: RunOutcome = RunOutcome.RUNNING
    operations_done: int = 0
    operations_total: int = 0
    plans: int = 0
    replans: int = 0
    faults: int = 0
    duration: float = 0.0  # on the controller's clock (virtual in-process)
    dropped: int = 0  # records not written: the disk did not keep up (a replay of such a run is refused)
    note: str = ""  # why it ended, when not finished


class StateRecord(msgspec.Struct, kw_only=True, omit_defaults=True):
    values: dict[str, Value] = msgspec.field(default_factory=dict)  # by variable path; changed ones only
    status: HubStatus | None = None  # None in-process: no hub
    detail: str = ""
    mirror_seq: int | None = None  # the seq of ours the hub mirrors


HubState = tuple[str, HubStatus, str, int | None]  # resource, status, detail, mirrored seq of ours


class StatesRecord(msgspec.Struct, array_like=True):
    values: dict[str, Value]  # by variable path: the batch's changed ones
    hubs: list[HubState]  # of the resources whose status changed or whose values did, in arrival order


class _ResourceOf(dict[str, str]):
    """A variable path's resource (`nr.run_m` -> `nr`), worked out once per path."""

    def __missing__(self, path: str) -> str:
        resource = self[path] = path.split(".", 1)[0]
        return resource


class StatesFilter:
    """What of each ingested batch, taken in order, a `states` row keeps: the values that changed, and the
    hub state of each resource whose hub state changed or whose values did (None: nothing to store)."""

    def __init__(self) -> None:
        self._known: dict[str, HubState] = {}
        self._resource_of = _ResourceOf()

    def row(self, changed: dict[str, Value], hub_states: list[HubState]) -> StatesRecord | None:
        known = self._known
        moved = {self._resource_of[path] for path in changed} if changed else ()
        hubs = []
        for item in hub_states:
            resource = item[0]
            if known.get(resource) != item:
                known[resource] = item
                hubs.append(item)
            elif resource in moved:
                hubs.append(item)
        return StatesRecord(changed, hubs) if changed or hubs else None


def expand_states(batch: StatesRecord) -> list[tuple[str, StateRecord]]:
    """A `states` row as the per-resource records it stands for: the resources with a hub state first, in
    arrival order, then those whose values came without one (in-process: no hub)."""
    hubs = {hub[0]: hub for hub in batch.hubs}
    by_resource: dict[str, dict[str, Value]] = {resource: {} for resource in hubs}
    for path, value in batch.values.items():
        by_resource.setdefault(path.split(".", 1)[0], {})[path] = value
    records = []
    for resource, values in by_resource.items():
        hub = hubs.get(resource)
        records.append((resource, StateRecord(values=values) if hub is None else
                        StateRecord(values=values, status=hub[1], detail=hub[2], mirror_seq=hub[3])))
    return records


class CommandRecord(msgspec.Struct, kw_only=True):
    values: dict[str, Value]  # every command variable of the resource, by path
    seq: int


class LivelinessRecord(msgspec.Struct, kw_only=True):
    alive: bool


class WatchdogRecord(msgspec.Struct, kw_only=True):
    verdict: WatchdogVerdict
    detail: str = ""


class TickRecord(msgspec.Struct, kw_only=True):
    pass


class RestoreRecord(msgspec.Struct, kw_only=True):
    values: dict[str, Value]


class HoldRecord(msgspec.Struct, kw_only=True):
    resources: list[str]  # held: sent no command, disabled
    paths: list[str]  # their command variables, unknown to the core


class PlanRequestRecord(msgspec.Struct, kw_only=True):
    generation: int
    goals: list[str]
    reason: str  # ReplanReason value
    detail: str = ""
    disabled: list[str] = msgspec.field(default_factory=list)
    start: str = ""  # state_hash of the state planned from


class StepRecord(msgspec.Struct, array_like=True):
    transition: str
    outcome: int


class PlanRecord(msgspec.Struct, kw_only=True):
    generation: int
    answer: PlanAnswer
    taken: bool  # the controller adopted it (a late first answer or a longer improvement is not)
    goals: list[str]
    reason: str = ""  # the request's ReplanReason value
    detail: str = ""
    found: bool = True
    steps: list[StepRecord] = msgspec.field(default_factory=list)
    no_plan: str = ""  # why there is none (found False; "" with no goals)
    unreachable: list[str] = msgspec.field(default_factory=list)
    proven: bool = False
    ms: float = 0.0  # the planner's wall time for this answer
    member: str = ""  # the portfolio member that found it
    expansions: int = 0
    minimal: bool = False
    planned_alone: str = ""  # the one goal planned alone when all together had no plan in the budget
    execution: str = ""  # the order the plan runs in (an `Execution`), "" the engine's own


class OperationRecord(msgspec.Struct, kw_only=True, rename={"before": "from", "after": "to"}):
    before: OperationState
    after: OperationState


class RequestRecord(msgspec.Struct, kw_only=True):
    request: ConsoleRequest
    accepted: bool
    reason: str = ""


DATA_TYPES: dict[RecordKind, Any] = {  # Any: ConsoleEvent is a union of Struct types, not one type
    RecordKind.STATE: StateRecord,
    RecordKind.STATES: StatesRecord,
    RecordKind.COMMAND: CommandRecord,
    RecordKind.LIVELINESS: LivelinessRecord,
    RecordKind.WATCHDOG: WatchdogRecord,
    RecordKind.TICK: TickRecord,
    RecordKind.RESTORE: RestoreRecord,
    RecordKind.HOLD: HoldRecord,
    RecordKind.PLAN_REQUEST: PlanRequestRecord,
    RecordKind.PLAN: PlanRecord,
    RecordKind.OPERATION: OperationRecord,
    RecordKind.REQUEST: RequestRecord,
    RecordKind.EVENT: ConsoleEvent,
}

RecordData = (StateRecord | CommandRecord | LivelinessRecord | WatchdogRecord | TickRecord | RestoreRecord
              | HoldRecord | PlanRequestRecord | PlanRecord | OperationRecord | RequestRecord | ConsoleEvent)


def station_model_hash(model: Model) -> str:
    """A stable hash of the whole model (its variables, transitions, operations and specifications)."""
    return hashlib.sha256(repr(model).encode()).hexdigest()[:16]


def state_hash(state: tuple[Value, ...]) -> str:
    """A short hash of a state tuple: a replay checks it plans from the same state without storing it."""
    return hashlib.blake2b(msgspec.msgpack.encode(state), digest_size=8).hexdigest()
