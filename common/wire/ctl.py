"""What the controller publishes under `{station}/ctl/` and the console's requests: plain msgspec structs.

The controller's event log is typed: each `Event` subclass is one kind of event (its `kind` on the
wire), with the fields a program acts on and a `text` for people. Why the controller plans again is a
`ReplanCause`: a `ReplanReason` its decisions depend on, and a detail for people.
"""

from __future__ import annotations

import enum
from collections.abc import Iterable
from typing import ClassVar

import msgspec

from common.model import OperationState
from common.model.predicates import format_value
from common.wire.messages import Message
from common.wire.orders import Order


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
    guard: str  # a pending step of the plan under way: what it waits for now (its guard, or the specification)
    done: bool


class PlanInfo(msgspec.Struct, frozen=True, omit_defaults=True):
    """The plan under way, in a status: by id (its steps and guards: the queryable `{station}/ctl/plan/{id}`)
    and which of its steps are done, a bit per step (`done_mask`)."""

    id: int  # 0: no plan (for `goals`, if any); ids count up per controller
    goals: list[str] = msgspec.field(default_factory=list)
    steps: int = 0
    done: bytes = b""

    def is_done(self, step: int) -> bool:
        byte = step >> 3
        return byte < len(self.done) and bool(self.done[byte] >> (step & 7) & 1)

    @property
    def done_count(self) -> int:
        return sum(bin(b).count("1") for b in self.done)


def done_mask(done: Iterable[int], steps: int) -> bytes:
    """`PlanInfo.done` of the steps `done` (indices) of a plan of `steps` steps."""
    mask = bytearray((steps + 7) // 8)
    for j in done:
        mask[j >> 3] |= 1 << (j & 7)
    return bytes(mask)


class PlanDetails(Message, kw_only=True):
    """The reply of `{station}/ctl/plan/{id}`: the plan's steps with their guards. For the plan under way
    (`current`) done and what each pending step waits for are as of the query; an older plan's steps
    are as they were when it was dropped."""

    id: int
    goals: list[str]
    steps: list[PlanStepInfo]
    current: bool


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


# --- why the controller plans (again) ----------------------------------------------------------

class ReplanReason(enum.StrEnum):
    """Why a plan is due; the value is how the event log says it."""

    START = "start"
    LEFT_PLAN = "the state left the plan"  # detail: the variables off the plan's trace
    STEP_BLOCKED = "the next step can no longer fire"  # detail: the step
    HEALTH_CHANGED = "resource health changed"  # detail: the resources disabled now
    RESTORED = "restored state"
    GOALS_CHANGED = "goals changed"
    GOALS_NOT_REACHED = "plan complete but goals not reached"
    GOALS_WITHOUT_PLAN = "planning without the goals that have no plan"
    RESUMED = "resumed"
    STOPPED_BY_OPERATOR = "stopped by the operator"  # detail: the operation
    RESET_BY_OPERATOR = "reset by the operator"  # detail: the operation
    SAFE_AGAIN = "no forbidden state holds any more"
    MIRROR_TAKEN = "a held resource's command state arrived"  # detail: the resource
    # detail: the step and the effect it waited for (controller/engine.py holds a step that would overtake it)
    RACE_HOLD_EXPIRED = "a step held for an effect due waited longer than the effect takes"


_CAUSE_TEXT = {  # how a reason and its detail read where it is not "reason: detail"
    ReplanReason.HEALTH_CHANGED: "{reason} (disabled: {detail})",
    ReplanReason.STOPPED_BY_OPERATOR: "operation {detail} {reason}",
    ReplanReason.RESET_BY_OPERATOR: "operation {detail} {reason}",
}


class ReplanCause(msgspec.Struct, frozen=True):
    reason: ReplanReason
    detail: str = ""

    @property
    def text(self) -> str:
        if not self.detail:
            return self.reason.value
        return _CAUSE_TEXT.get(self.reason, "{reason}: {detail}").format(reason=self.reason, detail=self.detail)


# --- the event log ------------------------------------------------------------------------------

class Event(msgspec.Struct, frozen=True, tag_field="kind"):
    """One entry of the controller's event log (`StatusMessage.events`), or of the console's own notes."""

    fault: ClassVar[bool] = False  # something went wrong that an operator should see
    template: ClassVar[str] = ""  # `text`, from the event's fields by name

    @property
    def text(self) -> str:
        return self.template.format(**msgspec.structs.asdict(self))


class Replanned(Event, tag="replan", frozen=True):
    """The plan under way (if any) is dropped and a new one asked for."""

    cause: ReplanCause
    template: ClassVar[str] = "replan: {cause.text}"


class PlanKept(Event, tag="plan_kept", frozen=True):
    """The state left the plan, but the rest of the plan still reaches the goals from there."""

    steps: int
    cause: ReplanCause
    template: ClassVar[str] = "plan kept: {steps} steps still reach the goals ({cause.text})"


class ShorterPlan(Event, tag="shorter_plan", frozen=True):
    """The planner kept searching and found a shorter way from where the station is: it replaces the rest."""

    steps: int
    instead_of: int
    method: str
    template: ClassVar[str] = "shorter plan taken: {steps} steps left instead of {instead_of} ({method})"


class FasterPlan(Event, tag="faster_plan", frozen=True):
    """The planner found the rest of the plan in an order the engine finishes sooner (controller/retime.py), no
    longer in steps: it replaces the rest."""

    steps: int
    seconds: float  # its predicted finish, from now
    instead_of: float  # the predicted finish of the rest it replaces
    method: str
    template: ClassVar[str] = ("faster plan taken: {steps} steps predicted to take {seconds:.1f} s instead of "
                               "{instead_of:.1f} s ({method})")


class PlannedAlone(Event, tag="planned_alone", frozen=True):
    """The goals together had no plan within the budget: one of them is planned alone, for progress."""

    operation: str
    goals: int
    reason: str
    template: ClassVar[str] = ("planned {operation} alone: {goals} goals together were not solved within the budget "
                               "({reason})")


class NoPlanFound(Event, tag="no_plan", frozen=True):
    """Goals without a plan: shown unreachable (`proven`) or not found within the budget; said once per goal
    and reason, not at every retry."""

    operations: list[str]
    proven: bool
    reason: str
    fault: ClassVar[bool] = True

    @property
    def text(self) -> str:
        kind = "unreachable" if self.proven else "not found in time"
        return f"no plan ({kind}) for {', '.join(self.operations)}: {self.reason}"


class PlanFound(Event, tag="plan_found", frozen=True):
    """A goal that had no plan has one again."""

    operation: str
    attempts: int
    template: ClassVar[str] = "plan found for {operation} after {attempts} attempt(s) without one"


class Livelock(Event, tag="livelock", frozen=True):
    """The same goals were asked again and again from one state, no progress in between, because an effect the
    plan needed never came: the operations go to `error` (retried with backoff, until `requests` reaches the
    limit). Said once per diagnosis."""

    operations: list[str]
    effect: str  # the effect transition that never happened
    diagnosis: str  # what never happened and what took its condition away
    requests: int  # how often these goals were asked from that state since the last progress
    fault: ClassVar[bool] = True

    @property
    def text(self) -> str:
        return (f"livelock: {self.diagnosis}; asked {self.requests} times from one state without progress: "
                f"{', '.join(self.operations)} in error")


class HubAlive(Event, tag="hub_alive", frozen=True):
    """The hub's liveliness token appeared (a start or a reconnection)."""

    hub: str
    template: ClassVar[str] = "hub {hub} alive"


class HubGone(Event, tag="hub_gone", frozen=True):
    """The hub's liveliness token went away: its resources go unhealthy."""

    hub: str
    template: ClassVar[str] = "hub {hub} gone"
    fault: ClassVar[bool] = True


class MirrorsMissing(Event, tag="mirrors_missing", frozen=True):
    """At start, these hubs' resources (by hub) sent no mirror in time: they are held (sent no command) until
    their mirrors arrive, and their command state is then taken from the mirrors."""

    resources: dict[str, list[str]]

    @property
    def report(self) -> str:
        return "; ".join(f"hub {hub}: {', '.join(names)}" for hub, names in sorted(self.resources.items()))

    @property
    def text(self) -> str:
        return f"start: no mirror from {self.report}: held, no command until their mirrors arrive"


class HoldReleased(Event, tag="hold_released", frozen=True):
    """A held resource's command state is known again: from its mirror, or (its hub restarted and has no
    command) the model's initial values, which make no specification hold."""

    resource: str
    source: str
    template: ClassVar[str] = "{resource} no longer held: its commands resume from {source}"


class ForbiddenState(Event, tag="forbidden_state", frozen=True):
    """A specification's forbidden state holds on the measured and estimated state (a device did what the
    model does not say, or an override): no deliberate transition fires until it clears."""

    specification: str
    values: dict[str, bool | int | str]  # the variables that make it hold
    fault: ClassVar[bool] = True

    @property
    def text(self) -> str:
        values = ", ".join(f"{p} = {format_value(v)}" for p, v in self.values.items())
        return f"forbidden state: {self.specification} holds ({values}): deliberate transitions stopped"


class ForbiddenStateCleared(Event, tag="forbidden_state_cleared", frozen=True):
    """The specification's forbidden state no longer holds."""

    specification: str
    template: ClassVar[str] = "forbidden state cleared: {specification} no longer holds"


class RequestAnswered(Event, tag="request", frozen=True):
    """A console's request and the controller's answer."""

    request: str  # ConsoleRequest.describe()
    accepted: bool
    detail: str = ""  # why it was refused, or what follows from accepting it
    origin: str = ""  # who asked (user@host)

    @property
    def text(self) -> str:
        origin = f" ({self.origin})" if self.origin else ""
        detail = f": {self.detail}" if self.detail else ""
        return f"console{origin}: {self.request} {'accepted' if self.accepted else 'refused'}{detail}"


class ControllerChanged(Event, tag="controller_changed", frozen=True):
    """The console sees another controller publish (a restart)."""

    controller: str
    previous: str
    template: ClassVar[str] = "controller {controller} (was {previous})"


class Unhealthy(Event, tag="unhealthy", frozen=True):
    """The watchdog's verdict: the resource is unhealthy (the console notes it from the status's health)."""

    resource: str
    reason: str
    template: ClassVar[str] = "watchdog: {resource} unhealthy: {reason}"
    fault: ClassVar[bool] = True


class Recovered(Event, tag="recovered", frozen=True):
    """The watchdog's verdict: the resource is healthy again."""

    resource: str
    template: ClassVar[str] = "watchdog: {resource} recovered"


class SupervisorCalled(Event, tag="supervisor_called", frozen=True):
    """An operator calls the supervisor from the operator's page (its hub holds a token while the call stands)."""

    hub: str
    resource: str
    template: ClassVar[str] = "{resource} calls the supervisor (hub {hub})"
    fault: ClassVar[bool] = True


class SupervisorCallEnded(Event, tag="supervisor_call_ended", frozen=True):
    """The operator's call for the supervisor ended: answered (the station moved on) or its hub stopped."""

    hub: str
    resource: str
    template: ClassVar[str] = "{resource}: the call for the supervisor ended (hub {hub})"


class OrderStarted(Event, tag="order_started", frozen=True):
    """The station took the next order: its product's variables got their start values, its operations are
    requested (controller/production/book.py)."""

    order: int
    product_id: str
    variant: str
    operations: int
    template: ClassVar[str] = "order {order} {product_id} ({variant}) started: {operations} operations"


class OrderFinished(Event, tag="order_finished", frozen=True):
    """Every operation of the running order finished: its product left, its state is archived with it and the
    product's variables and operations are back at their initial values. `line`: its cycle and the busiest
    resources (controller/production/throughput.py `order_line`)."""

    order: int
    product_id: str
    variant: str
    cycle_s: float
    line: str
    template: ClassVar[str] = "{line}"


ConsoleEvent = (Replanned | PlanKept | ShorterPlan | FasterPlan | PlannedAlone | NoPlanFound | PlanFound | Livelock
                | HubAlive | HubGone | MirrorsMissing | HoldReleased | ForbiddenState | ForbiddenStateCleared
                | RequestAnswered | Unhealthy | Recovered | ControllerChanged | OrderStarted | OrderFinished
                | SupervisorCalled | SupervisorCallEnded)


EVENT_WINDOW = 20  # the newest events of a full status
RECENT_ORDERS = 5  # the newest finished orders a status carries


class OrderDone(msgspec.Struct, frozen=True):
    """A finished order, on the order book's clock (wall time live, virtual time in process)."""

    order: int
    product_id: str
    variant: str
    started: float
    finished: float

    @property
    def cycle_s(self) -> float:
        return self.finished - self.started


class ProductionInfo(msgspec.Struct, frozen=True):
    """The station's orders, in a status: the running one, how many wait and are done, the newest finished."""

    current: Order | None = None
    queued: int = 0
    done: int = 0
    recent: list[OrderDone] = msgspec.field(default_factory=list)  # the newest RECENT_ORDERS, newest last


class ResourceIdleInfo(msgspec.Struct, frozen=True):
    """One resource's time with nothing to do, and what its commands waited for (longest first, a few)."""

    resource: str
    idle_s: float
    waits: list[tuple[str, float]] = msgspec.field(default_factory=list)


class CycleInfo(msgspec.Struct, frozen=True):
    """The goal set's timing, in a status, in seconds since the controller started (controller/cycle.py):
    the predicted finish of the plan under way, the lower bound (no schedule of the work ends sooner: the
    busiest resource's necessary work, the run's longest causal chain, and once the run is done the work the
    specifications keep apart), and each resource's idle time.
    `cycle_s`: the time so far, or when every operation finished."""

    cycle_s: float
    predicted_s: float
    bound_s: float
    chain_s: float = 0.0  # the run's longest causal chain (controller/causal_chain.py)
    busiest: str = ""  # the resource with the most work done
    busiest_work_s: float = 0.0
    idle: list[ResourceIdleInfo] = msgspec.field(default_factory=list)
    apart_s: float = 0.0  # the work the specifications keep apart, once the run is done (controller/exclusions.py)
    apart: list[str] = msgspec.field(default_factory=list)  # whose work that is


class StatusMessage(Message, kw_only=True):
    """`{station}/ctl/status`, a few times a second and on every operation change: what changed since the
    controller's previous status (`seq` counts them), and every few seconds (`full`) the whole picture,
    which a query on the key also answers. A delta carries the operations and health entries that changed,
    `plan` when another plan is under way, `plan_done` when its done steps changed, and the events logged
    since; a full status every operation and resource, the plan and the last EVENT_WINDOW events.
    `controller/console/statusview.py` merges them back into full statuses."""

    station: str
    controller: str
    time: float
    uptime: float
    seq: int = 0
    full: bool = True
    operations: list[OperationInfo] = msgspec.field(default_factory=list)
    health: list[ResourceHealthInfo] = msgspec.field(default_factory=list)
    plan: PlanInfo | None = None  # a delta: None while the same plan is under way
    plan_done: bytes | None = None  # a delta: the plan's new `done`, None while unchanged
    plans: int = 0
    replans: int = 0
    no_plans: int = 0
    abilities: int = 0
    paused: bool = False
    finished: bool = False
    events: list[ConsoleEvent] = msgspec.field(default_factory=list)  # newest last
    events_total: int = 0  # events the controller logged since it started
    loop: LoopStats | None = None  # None from a controller that does not measure itself
    production: ProductionInfo | None = None  # None from a station running no orders (or an older controller)
    cycle: CycleInfo | None = None  # None from an older controller


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
    override: bool = False  # force: even into a state a specification forbids (logged at WARNING)

    def describe(self) -> str:
        """The request as the event log and the console show it, in the model's notation."""
        action = self.action
        if action in ("start", "stop", "reset"):
            return f"{action} {self.operation}"
        if action == "force":
            value = "?" if self.value is None else format_value(self.value)
            return f"force {self.path} := {value}{' (override)' if self.override else ''}"
        if action == "unforce":
            return f"unforce {self.path}"
        if action == "confirm" and self.resource:
            return f"confirm {self.resource}"
        return action


class ConsoleReply(Message, kw_only=True):
    accepted: bool
    reason: str = ""  # why it was refused, or what follows from accepting it
