"""The console's panels as rows of text: pure functions of what the controller published.

Each panel is a dict `key -> row` (a tuple of cells); `RowTable` (table.py)
updates only the cells that changed. Times shown are coarse (whole seconds; a hub's
state age as "< 1 s" while it is fresh) so that a steady station yields unchanged rows,
and a redraw costs what actually changed.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from rich.text import Text

from common.model import Kind, OperationState, ParseError, Value, parse_action
from common.model.predicates import Ref, format_value
from common.wire.ctl import (
    ControllerChanged,
    CycleInfo,
    Event,
    ForbiddenStateCleared,
    OperationInfo,
    PlanDetails,
    PlanInfo,
    ProductionInfo,
    Recovered,
    Replanned,
    RequestAnswered,
    StateSnapshot,
    StatusMessage,
    Unhealthy,
)
from common.wire.selftest_report import SelftestMessage

from .station import StationInfo

Cell = str | Text
Row = tuple[Cell, ...]

RECENT_S = 10.0  # "recently changed": within this many seconds
CHANGED_SHOWN_S = 60.0  # the "changed" column is blank for older changes, so old rows never redraw
GOAL_WIDTH = 48
GUARD_WIDTH = 64
ERROR_WIDTH = 60

RESOURCE_COLUMNS = ("resource", "hub", "mode", "health", "state age", "mirror", "self-test")
OPERATION_COLUMNS = ("operation", "state", "goal", "in state", "error")
PLAN_COLUMNS = ("#", "", "step", "kind", "waits for")
STATE_COLUMNS = ("variable", "kind", "value", "forced", "changed")

OP_STYLES = {OperationState.INITIAL: "", OperationState.EXECUTING: "bold cyan", OperationState.FINISHED: "green",
             OperationState.ERROR: "bold red"}
KIND_ORDER: tuple[Kind | None, ...] = (None, Kind.MEASURED, Kind.ESTIMATED, Kind.COMMAND)


def clip(text: str, width: int) -> str:
    return text if len(text) <= width else text[: width - 1] + "…"


def duration(seconds: float) -> str:
    """`0:07`, `12:30`, `1:02:03`: whole seconds, as an operator reads a clock."""
    total = max(0, int(seconds))
    hours, rest = divmod(total, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


# --- resources ---------------------------------------------------------------------------------

def resource_rows(status: StatusMessage, info: StationInfo, selftests: Mapping[str, SelftestMessage]) -> dict[str, Row]:
    rows: dict[str, Row] = {}
    for h in status.health:
        if h.healthy:
            health = Text(f"ok ({h.note})", "yellow") if h.note else Text("ok", "green")
        else:
            health = Text(h.reason or "unhealthy", "bold red")
        age = "-" if h.age is None else "< 1 s" if h.age < 1.0 else f"{h.age:.1f} s"
        mirror = Text("ok", "green") if h.mirror_lag == 0 else Text(f"{h.mirror_lag} behind", "yellow")
        rows[h.resource] = (h.resource, h.hub, info.modes.get(h.resource, "?"), health, age, mirror,
                            _selftest(selftests.get(h.hub), h.resource))
    return rows


def _selftest(report: SelftestMessage | None, resource: str) -> Cell:
    if report is None:
        return "-"
    device = next((d for d in report.devices if d.resource == resource), None)
    if device is None:
        return "-"
    return Text("pass", "green") if device.ok else Text("FAIL", "bold red")


# --- operations --------------------------------------------------------------------------------

class OperationClock:
    """When each operation entered its state. The controller times starts and finishes (`since`);
    a stop, a reset or an error it does not time, so the console takes the status that first
    showed the new state."""

    def __init__(self) -> None:
        self._seen: dict[str, tuple[str, float, float]] = {}  # name -> (state, controller's since, since used)

    def since(self, op: OperationInfo, uptime: float) -> float:
        seen = self._seen.get(op.name)
        if seen is None:
            used = op.since
        elif seen[0] != op.state:
            used = op.since if op.since != seen[1] else uptime
        else:
            used = seen[2]
        self._seen[op.name] = (op.state, op.since, used)
        return used


def operation_rows(status: StatusMessage, info: StationInfo, clock: OperationClock) -> dict[str, Row]:
    rows: dict[str, Row] = {}
    for op in status.operations:
        since = clock.since(op, status.uptime)
        rows[op.name] = (op.name, Text(op.state, OP_STYLES.get(op.state, "")),
                         clip(info.goals.get(op.name, ""), GOAL_WIDTH), duration(status.uptime - since),
                         Text(clip(op.error, ERROR_WIDTH), "red"))
    return rows


# --- the plan ----------------------------------------------------------------------------------

def plan_rows(plan: PlanInfo | None, details: PlanDetails | None) -> dict[str, Row]:
    """The steps of the plan under way (`details`, from the plan queryable) with their done marks from the
    status, newer than the details; none while the details of this plan have not come."""
    rows: dict[str, Row] = {}
    if plan is None or details is None or details.id != plan.id:
        return rows
    for j, step in enumerate(details.steps):
        done = plan.is_done(j)
        mark = Text("✔", "green") if done else Text("·", "cyan")
        waits = "" if done else clip(step.guard, GUARD_WIDTH)
        rows[str(j)] = (str(j + 1), mark, step.transition, step.kind, waits)
    return rows


def plan_summary(plan: PlanInfo | None, cycle: CycleInfo | None = None) -> str:
    """The plan's progress, with its predicted finish and the goal set's lower bound when the status has them."""
    timing = "" if cycle is None else f"; ends ~{cycle.predicted_s:.1f} s, bound {cycle.bound_s:.1f} s"
    if plan is None or not plan.id:
        return "no plan" + (f" for {', '.join(plan.goals)}" if plan is not None and plan.goals else "") + timing
    return f"{plan.done_count}/{plan.steps} steps for {clip(', '.join(plan.goals), 60)}{timing}"


def production_summary(production: ProductionInfo | None) -> str:
    """The current order, the queue and the last cycle times, for the status line ("" when the station runs no
    orders)."""
    if production is None:
        return ""
    current = production.current
    running = f"order {current.id} {current.product_id} ({current.variant})" if current is not None else "no order"
    recent = ", ".join(f"{done.variant} {done.cycle_s:.1f} s" for done in production.recent[-3:])
    return (f"{running}, {production.queued} queued, {production.done} done"
            + (f"; last cycles: {recent}" if recent else ""))


# --- global state ------------------------------------------------------------------------------

@dataclass(frozen=True)
class StateFilter:
    text: str = ""  # a substring of the path
    kind: Kind | None = None
    recent: bool = False  # changed within RECENT_S

    def next_kind(self) -> StateFilter:
        following = KIND_ORDER[(KIND_ORDER.index(self.kind) + 1) % len(KIND_ORDER)]
        return StateFilter(self.text, following, self.recent)

    def describe(self) -> str:
        parts = [f"kind {self.kind.value if self.kind else 'all'}"]
        if self.recent:
            parts.append(f"changed in the last {RECENT_S:.0f} s")
        if self.text:
            parts.append(f"path has {self.text!r}")
        return ", ".join(parts)


class StateView:
    """The newest value of every variable and when the console saw it change (the first snapshot
    after connecting changes nothing: the console cannot know)."""

    def __init__(self, kinds: Mapping[str, Kind]) -> None:
        self.kinds = kinds
        self.values: dict[str, Value] = {}
        self.forced: frozenset[str] = frozenset()
        self.changed_at: dict[str, float] = {}
        self._snapshot_time: float | None = None

    def update(self, snapshot: StateSnapshot, now: float) -> None:
        if snapshot.time == self._snapshot_time:
            return
        first = self._snapshot_time is None
        self._snapshot_time = snapshot.time
        for path, value in snapshot.values.items():
            known = path in self.values
            old = self.values.get(path)
            self.values[path] = value
            # type(): True == 1, but a bool never becomes an int in one domain; cheap and exact
            if known and not first and (old != value or type(old) is not type(value)):
                self.changed_at[path] = now
        self.forced = frozenset(snapshot.forced)

    def rows(self, chosen: StateFilter, now: float) -> dict[str, Row]:
        rows: dict[str, Row] = {}
        text = chosen.text.lower()
        for path, value in self.values.items():
            kind = self.kinds.get(path)
            changed = self.changed_at.get(path)
            age = None if changed is None else now - changed
            if (text and text not in path.lower()) or (chosen.kind is not None and kind is not chosen.kind) \
                    or (chosen.recent and (age is None or age > RECENT_S)):
                continue
            forced = path in self.forced
            shown = format_value(value)
            rows[path] = (path, kind.value if kind else "?", Text(shown, "bold yellow") if forced else shown,
                          Text("FORCED", "bold yellow") if forced else "",
                          f"{int(age)} s ago" if age is not None and age < CHANGED_SHOWN_S else "")
        return rows


# --- events ------------------------------------------------------------------------------------

class EventFeed:
    """New events of the controller's event log. A status carries the last events only: what is new is
    what follows the longest overlap with the previous window; a new controller starts afresh."""

    def __init__(self) -> None:
        self._controller = ""
        self._window: list[Event] = []
        self._healthy: dict[str, bool] = {}

    def new(self, status: StatusMessage) -> list[Event]:
        events: list[Event] = []
        if status.controller != self._controller:
            if self._controller:
                events.append(ControllerChanged(status.controller, self._controller))
            self._controller, self._window, self._healthy = status.controller, [], {}
        window: list[Event] = list(status.events)
        previous = self._window
        overlap = next(k for k in range(min(len(previous), len(window)), -1, -1)
                       if previous[len(previous) - k:] == window[:k])
        events += window[overlap:]
        self._window = window
        return events + self._health_changes(status)

    def _health_changes(self, status: StatusMessage) -> list[Event]:
        # The watchdog's verdicts are in the status, not in the controller's log: the console notes the edges.
        events: list[Event] = []
        for h in status.health:
            before = self._healthy.get(h.resource)
            if before is None and h.healthy:
                pass
            elif not h.healthy and before is not False:
                events.append(Unhealthy(h.resource, h.reason))
            elif h.healthy and before is False:
                events.append(Recovered(h.resource))
            self._healthy[h.resource] = h.healthy
        return events


EVENT_STYLES: dict[type[Event], str] = {Recovered: "green", ForbiddenStateCleared: "green", Replanned: "yellow",
                                        RequestAnswered: "cyan"}


def event_text(event: Event) -> Text:
    return Text(event.text, "bold red" if event.fault else EVENT_STYLES.get(type(event), ""))


# --- the force input ---------------------------------------------------------------------------

OVERRIDE = "!override"


def split_override(text: str) -> tuple[str, bool]:
    """`path = value !override`: a force even into a state a specification forbids (the controller logs it)."""
    text = text.strip()
    if text.endswith(OVERRIDE):
        return text[:-len(OVERRIDE)].strip(), True
    return text, False


def parse_force(text: str) -> tuple[str, Value]:
    """`nr.run_c = true` (or `:=`, the model's notation) as (path, value); ValueError says what is wrong."""
    text = text.strip()
    if ":=" not in text:
        text = text.replace("=", ":=", 1)
    try:
        action = parse_action(text)
    except ParseError as exc:
        raise ValueError(f"expected `path = value`: {str(exc).splitlines()[0]}") from None
    if isinstance(action.value, Ref):
        raise ValueError(f"force takes a value, not another variable ({action.value.path})")
    return action.path, action.value
