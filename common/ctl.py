"""What the controller publishes under `{station}/ctl/` and the console's requests: plain msgspec structs."""

from __future__ import annotations

import msgspec

from common.messages import Message
from common.model import OperationState
from common.model.predicates import format_value


class ResourceHealthInfo(msgspec.Struct, frozen=True):
    resource: str
    hub: str
    healthy: bool
    reason: str = ""
    age: float | None = None  # seconds since its last state
    mirror_lag: int = 0
    note: str = ""  # reported by its hub but not about our commands (a refused command of another controller)


class OperationInfo(msgspec.Struct, frozen=True):
    name: str
    state: OperationState
    error: str = ""
    since: float = 0.0  # controller clock when it entered this state


class PlanStepInfo(msgspec.Struct, frozen=True):
    resource: str
    transition: str
    kind: str
    guard: str
    done: bool


class LoopStats(msgspec.Struct, frozen=True):
    """How the controller's loop kept up since its previous status (`window_s` seconds)."""

    window_s: float
    ticks: int
    tick_ms_median: float
    tick_ms_p99: float
    tick_ms_max: float
    states: int  # hub states ingested
    states_dropped: int  # replaced by a newer state of the same resource before they were ingested
    state_age_ms_median: float  # from the hub's publication (its `time`) to ingestion
    state_age_ms_p99: float
    state_age_ms_max: float


class StatusMessage(Message, kw_only=True):
    """`{station}/ctl/status`, at a few Hz and on every operation change."""

    station: str
    controller: str
    time: float
    uptime: float
    operations: list[OperationInfo]
    health: list[ResourceHealthInfo]
    plan: list[PlanStepInfo]  # the current plan's steps, done or not
    plan_goals: list[str]
    plans: int
    replans: int
    no_plans: int
    abilities: int
    paused: bool = False
    finished: bool = False
    events: list[str] = msgspec.field(default_factory=list)  # newest last
    loop: LoopStats | None = None  # None from a controller that does not measure itself


class StateSnapshot(Message, kw_only=True):
    """`{station}/ctl/state`: the global state, every variable by path."""

    time: float
    values: dict[str, bool | int | str]
    forced: list[str] = msgspec.field(default_factory=list)


# --- the console's requests: a query on `{station}/ctl/request`, one ConsoleReply back ---------

ACTIONS = ("start", "reset", "stop", "pause", "resume", "confirm", "force", "unforce")


class ConsoleRequest(Message, kw_only=True):
    """An operator's action. `action` is one of ACTIONS; an unknown one is refused, not undecodable,
    so that an older controller answers a newer console with a reason."""

    action: str
    operation: str = ""  # start, reset, stop
    path: str = ""  # force, unforce
    value: bool | int | str | None = None  # force
    resource: str = ""  # confirm: the operator resource (default: the one that has an instruction)
    origin: str = ""  # who asks (user@host), for the controller's event log

    def describe(self) -> str:
        """The request as the event log and the console show it, in the model's notation."""
        action = self.action
        if action in ("start", "stop", "reset"):
            return f"{action} {self.operation}"
        if action == "force":
            return f"force {self.path} := {'?' if self.value is None else format_value(self.value)}"
        if action == "unforce":
            return f"unforce {self.path}"
        if action == "confirm" and self.resource:
            return f"confirm {self.resource}"
        return action


class ConsoleReply(Message, kw_only=True):
    accepted: bool
    reason: str = ""  # why it was refused, or what follows from accepting it
