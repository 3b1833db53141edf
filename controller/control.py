"""The controller's decisions, without I/O: which operations run, which goals are planned for,
when to replan, and what an unreachable goal does to its operation.

`ControlCore` owns the global state tuple. The control loop around it (controller/loop.py, which the
Zenoh controller, the in-process runner and replay drive) feeds it measurements, calls `tick()`, asks
`plan_request()` (planned off the event loop when live), hands the result back with `adopt()`, and
sends what changed. Every decision and note goes into its event log (controller/events.py).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Protocol

from common.config.modes import DEFAULT_EXECUTION, Execution
from common.model import RUNNING, Kind, OperationState, Predicate, Value
from common.model.compiled import CompiledModel, State
from common.wire.ctl import (
    FasterPlan,
    Livelock,
    NoPlanFound,
    PlanFound,
    PlanKept,
    ReplanCause,
    Replanned,
    ReplanReason,
    ShorterPlan,
)

from .engine import Engine, LostEffect, PlanProgress, TickResult
from .events import EventLog
from .kept_product import KeptProduct
from .livelock import PLAN_FAILED, LivelockWatch, Repeat
from .livelock import RETRIES as LIVELOCK_RETRIES
from .planner import Budget, NoPlan, Plan, Planner
from .planner.policy import RETRY_FIRST_S, RETRY_MAX_S, live_budget, solve_goals
from .safety import SafetyMonitor

AT_START = ReplanCause(ReplanReason.START)
# How much sooner a plan of as many steps must be predicted to end to replace the rest under way: the prediction
# counts each effect at its longest, and a switch for less than its own error is churn.
FASTER_BY = 0.01


class FinishEstimate(Protocol):
    """The predicted seconds a plan's steps not in `done` take from now (controller/cycle.py)."""

    def __call__(self, plan: Plan, done: frozenset[int]) -> float: ...


class InputListener(Protocol):
    """What a run recording hears from the core: inputs that come from inside the controller (persisted
    values and mirrors loaded, command variables unknown while their resource is held)."""

    def loaded(self, values: Mapping[str, Value]) -> None: ...
    def unknown_set(self, paths: list[str]) -> None: ...


@dataclass(frozen=True)
class PlanRequest:
    """A snapshot to plan from; `generation` tells a late answer from a current one."""

    generation: int
    start: State
    goals: dict[str, Predicate]
    disabled: frozenset[str]
    reason: ReplanCause = AT_START  # why a plan is due
    reuse: bool = True  # False: the remembered plan for these goals is not handed back (controller/livelock.py)
    # Finished operations' product goals the plan must leave holding (controller/kept_product.py).
    keep: dict[str, Predicate] = field(default_factory=dict)


@dataclass
class Force:
    """A variable the operator holds at `value`. `own` is what it holds without the force: the hub's
    newest measurement, or (estimated and command variables, which nothing writes while forced) its
    value before the force; `until` releases the force by itself once it holds (a confirmation)."""

    value: Value
    own: Value
    until: Callable[[State], bool] | None = None


@dataclass
class GoalError:
    """An operation whose goal has no plan: why, since when, and when it is tried again (backoff)."""

    reason: str
    since: float
    retry_at: float
    attempts: int = 1
    proven: bool = False  # shown unreachable, not merely not found within the budget
    livelock: bool = False  # it has plans, but the devices do not follow them (controller/livelock.py)


@dataclass
class ControlEvents:
    replans: int = 0
    plans: int = 0
    no_plans: int = 0
    abilities_started: int = 0
    log: EventLog = field(default_factory=EventLog)


class ControlCore:
    def __init__(self, compiled: CompiledModel, planner: Planner, clock: Callable[[], float] = time.monotonic,
                 *, budget: Budget | None = None, execution: Execution = DEFAULT_EXECUTION) -> None:
        """`execution`: the order the engine runs plans in (`[controller] execution`), unless the timed check
        chose a stricter one for a plan."""
        self.compiled = compiled
        self.model = compiled.model
        self.planner = planner
        self.budget = budget or live_budget()
        self.engine = Engine(compiled, execution=execution)
        self.clock = clock
        self.state: State = compiled.initial()
        self.requested: list[str] = []  # operations to start when their precondition holds
        self.disabled: frozenset[str] = frozenset()
        self.progress: PlanProgress | None = None
        self.planned_goals: frozenset[str] = frozenset()
        self.requested_goals: frozenset[str] = frozenset()  # of the plan under way
        self.generation = 0
        self.planning = False
        self.need_plan_reason: ReplanCause | None = AT_START
        self.errors: dict[str, GoalError] = {}  # operation -> why it has no plan, and when it is retried
        self.events = ControlEvents()
        self.paused = False  # the operator holds every deliberate transition: plan steps and operation starts
        self.forced: dict[int, Force] = {}  # by state index
        self._blocked: frozenset[str] = frozenset()  # writing a forced or reading an unknown variable
        self.unknown: frozenset[int] = frozenset()  # command variables of held resources (controller/command_hold.py)
        self.listener: InputListener | None = None  # told the values loaded and unknown beside the loop's inputs
        self.safety = SafetyMonitor(compiled)
        self._deliberate_names = frozenset(t.name for t in compiled.deliberate)
        self.measured_indices = {p: compiled.index[p] for p in self.model.paths_of_kind(Kind.MEASURED)}
        self.op_index = {op.name: compiled.index[op.state_path] for op in self.model.operations}
        self.livelock = LivelockWatch()
        self.kept_product = KeptProduct(compiled)
        self._lost: LostEffect | None = None  # why the plan just dropped failed, if an effect it needed was lost
        self._livelock_attempts: dict[str, int] = {}  # by operation, since an operation last finished
        self._livelocks_said: set[str] = set()  # effects diagnosed lost since an operation last finished
        self._sent: dict[str, str] = {}  # resource -> what last set it going (PlanProgress.sent)

    # --- inputs -------------------------------------------------------------------------
    def request(self, *operations: str) -> None:
        for name in operations:
            if name not in self.op_index:
                raise KeyError(f"no operation {name!r} in model {self.model.name!r}")
            if name not in self.requested:
                self.requested.append(name)

    def ingest(self, values: Mapping[str, Value]) -> dict[str, Value]:
        """Take measured values; those that changed (empty: nothing did), a forced variable's own value too."""
        hidden: dict[str, Value] = {}
        if self.forced:
            values, hidden = self._behind_forces(values)
        changed = {p: v for p, v in values.items() if self.state[self.measured_indices[p]] != v}
        if changed:
            self.state = self.compiled.with_values(self.state, changed)
        return changed | hidden if hidden else changed

    def set_disabled(self, resources: frozenset[str]) -> None:
        if resources != self.disabled:
            self.disabled = resources
            self._want_plan(ReplanCause(ReplanReason.HEALTH_CHANGED, ", ".join(sorted(resources)) or "none"))

    def load(self, values: Mapping[str, Value]) -> None:
        """Restore persisted or mirrored values of any kind (restart)."""
        self.state = self.compiled.with_values(self.state, values)
        if self.listener is not None:
            self.listener.loaded(values)
        self._want_plan(ReplanCause(ReplanReason.RESTORED))

    # --- queries ------------------------------------------------------------------------
    def op_state(self, name: str) -> OperationState:
        value = self.state[self.op_index[name]]
        # An operation's variable has the domain OPERATION_STATES: always one of its strings.
        assert isinstance(value, str), f"op.{name} holds {value!r}"
        return OperationState(value)

    def executing(self) -> list[str]:
        return [n for n, i in self.op_index.items() if self.state[i] in RUNNING]

    def all_finished(self) -> bool:
        return all(self.state[i] == OperationState.FINISHED for i in self.op_index.values())

    def _set_op_state(self, name: str, state: OperationState) -> None:
        # The member's plain string: the state tuple holds the model's domain values, as the hubs' do.
        self.state = self.compiled.with_values(self.state, {self.model.operation_by_name[name].state_path: state.value})

    def goals(self) -> dict[str, Predicate]:
        now = self.clock()
        goals = {}
        for name in self.executing():
            error = self.errors.get(name)
            if error is not None and now < error.retry_at:
                continue
            goals[name] = self.model.operation_by_name[name].goal
        return goals

    # --- the loop -----------------------------------------------------------------------
    def tick(self) -> TickResult:
        self._check_safety()
        paused = self.paused or self.safety.stopped
        result = self.engine.tick(self.state, requested=() if paused else self._startable(),
                                  progress=None if paused else self.progress,
                                  disabled=self.disabled, blocked=self._blocked, now=self.clock())
        self.state = result.state
        if self.forced:
            self._hold_forces()
        self.events.abilities_started += sum(1 for n in result.fired if n in self._deliberate_names)
        self._watch_progress(result)
        if result.replan is not None and not self._revalidate(result.replan):
            self._want_plan(result.replan)
            self._lost = result.lost
        for name in result.finished:
            self.errors.pop(name, None)
        goals = frozenset(self.goals())
        if goals != self.planned_goals and not (self.planning and goals == self.requested_goals):
            if self._only_finished_left(goals):
                # The rest of a shortest plan that keeps what is done is still shortest for what is left.
                self.planned_goals = goals
            else:
                self._want_plan(ReplanCause(ReplanReason.GOALS_CHANGED))
        if self.progress is not None and self.progress.complete and goals == self.planned_goals and goals:
            # Completed plan whose goals do not hold: the world moved on; plan again.
            self._want_plan(ReplanCause(ReplanReason.GOALS_NOT_REACHED))
        return result

    def _watch_progress(self, result: TickResult) -> None:
        """Only a finished operation is progress (controller/livelock.py)."""
        if result.finished:
            self.livelock.finished()
            self._livelock_attempts.clear()
            self._livelocks_said.clear()

    def _check_safety(self) -> None:
        events = self.safety.check(self.state, self.unknown)
        if events:
            for event in events:
                self.events.log.emit(event)
            if not self.safety.stopped:  # devices went on meanwhile, as after a pause: plan afresh
                self._want_plan(ReplanCause(ReplanReason.SAFE_AGAIN))

    def _startable(self) -> list[str]:
        """The requested operations whose start does not read an unknown command value."""
        if not self.unknown:
            return self.requested
        return [n for n in self.requested if not (self.engine.op_start[n].reads & self.unknown)]

    def _revalidate(self, cause: ReplanCause) -> bool:
        """After the state left the plan: keep the rest of it if the engine would still take it to the goals.

        Devices change what no plan step waits for (the camera sees the operator step out after a
        task); replanning for each would stall the station for a search.
        """
        progress = self.progress
        if progress is None or cause.reason is not ReplanReason.LEFT_PLAN:
            return False
        rest = [progress.plan.steps[j] for j in sorted(progress.pending())]
        goals = {name: self.model.operation_by_name[name].goal for name in self.planned_goals}
        if not rest or not goals:
            return False
        plan = self.planner.revalidate(self.state, rest, goals, self.disabled)
        if plan is None:
            return False
        self._follow(plan)
        self.events.log.emit(PlanKept(len(rest), cause))
        return True

    def _only_finished_left(self, goals: frozenset[str]) -> bool:
        """The plan under way planned for these goals and more, and the others are finished."""
        return (self.progress is not None and not self.planning and goals < self.planned_goals
                and all(self.op_state(n) is OperationState.FINISHED for n in self.planned_goals - goals))

    def _want_plan(self, cause: ReplanCause) -> None:
        if self.need_plan_reason is None:
            self.need_plan_reason = cause
        self.progress = None

    def plan_request(self) -> PlanRequest | None:
        """A planning job if one is due and none is under way."""
        if self.planning or self.need_plan_reason is None or self.safety.stopped:
            return None  # a plan from a forbidden state waits until it clears
        goals = self.goals()
        repeat = self._repeat(goals, self.need_plan_reason)
        if repeat is not Repeat.FIRST and repeat is not Repeat.AGAIN:
            goals = self.goals()  # the livelocked goals are in error now
        self.generation += 1
        self.planning = True
        self.requested_goals = frozenset(goals)
        if self.need_plan_reason.reason is not ReplanReason.START and goals:
            self.events.replans += 1
            self.events.log.emit(Replanned(self.need_plan_reason))
        reason, self.need_plan_reason = self.need_plan_reason, None
        keep = self.kept_product.goals(self.state, [*goals, *self.requested]) if goals else {}
        return PlanRequest(self.generation, self.state, goals, self.disabled, reason,
                           reuse=repeat is Repeat.FIRST, keep=keep)

    def _repeat(self, goals: Mapping[str, Predicate], cause: ReplanCause) -> Repeat:
        """Count this request; asked again in a loop that loses an effect, or too often, the goals go to error.
        Only a request because a plan failed counts (controller/livelock.py)."""
        lost, self._lost = self._lost, None
        if not goals:
            return Repeat.FIRST
        repeat, count = self.livelock.asked(frozenset(goals), self.state, plan_failed=cause.reason in PLAN_FAILED)
        if repeat is Repeat.GIVE_UP or (repeat is Repeat.LOOP and lost is not None):
            self._livelocked(sorted(goals), lost, count, retry=repeat is Repeat.LOOP)
        elif repeat is Repeat.LOOP:
            return Repeat.AGAIN  # a retry, or a loop whose cause is not known: planned afresh
        return repeat

    def _livelocked(self, names: list[str], lost: LostEffect | None, count: int, *, retry: bool) -> None:
        """The operations to `error`: with backoff if `retry` (LIVELOCK_RETRIES times), else until the operator
        starts them again."""
        now = self.clock()
        diagnosis = lost.text if lost is not None else f"no progress in {count} plans from one state"
        for name in names:
            attempts = self._livelock_attempts[name] = self._livelock_attempts.get(name, 0) + 1
            retried = retry and attempts <= LIVELOCK_RETRIES
            wait = min(RETRY_FIRST_S * 2 ** (attempts - 1), RETRY_MAX_S) if retried else math.inf
            previous = self.errors.get(name)
            self.errors[name] = GoalError(diagnosis, now if previous is None else previous.since, now + wait, attempts,
                                          livelock=True)
            self._set_op_state(name, OperationState.ERROR)
        said = lost.effect if lost is not None else ""
        if said not in self._livelocks_said:  # said once, not at every retry
            self._livelocks_said.add(said)
            self.events.log.emit(Livelock(names, lost.effect if lost is not None else "", diagnosis, count))
        self.progress = None

    def error_text(self, name: str) -> str:
        """Why an operation has no plan and when it is tried again ("" when it has one)."""
        error = self.errors.get(name)
        if error is None:
            return ""
        kind = "livelock" if error.livelock else "unreachable" if error.proven else "no plan found in time"
        if math.isinf(error.retry_at):
            return f"{kind}: {error.reason}; attempt {error.attempts}, not retried: stop and start it again"
        wait = max(0.0, error.retry_at - self.clock())
        return f"{kind}: {error.reason}; attempt {error.attempts}, retried in {wait:.0f} s"

    def next_retry(self) -> float | None:
        """When the first goal without a plan is tried again, if any."""
        return min((e.retry_at for e in self.errors.values() if not math.isinf(e.retry_at)), default=None)

    def solve(self, request: PlanRequest) -> Plan | NoPlan | None:
        result, note = solve_goals(self.planner, request, self.budget)
        if note is not None:
            self.events.log.emit(note)
        return result

    def adopt(self, request: PlanRequest, result: Plan | NoPlan | None) -> bool:
        """Take the answer to `request`; False if it came too late (a newer request is due or under way)."""
        self.planning = False
        if request.generation != self.generation or self.need_plan_reason is not None:
            return False  # the world changed while planning: a new request is already due
        self.planned_goals = frozenset(request.goals)
        if result is None:
            self.progress = None
            return True
        if isinstance(result, NoPlan):
            self.events.no_plans += 1
            now = self.clock()
            news = []
            for name in result.unreachable or tuple(request.goals):
                previous = self.errors.get(name)
                attempts = 1 if previous is None else previous.attempts + 1
                wait = min(RETRY_FIRST_S * 2 ** (attempts - 1), RETRY_MAX_S)
                self.errors[name] = GoalError(result.reason, now if previous is None else previous.since,
                                              now + wait, attempts, result.proven)
                if previous is None or previous.reason != result.reason:
                    news.append(name)
                self._set_op_state(name, OperationState.ERROR)
            if news:  # said once per goal and reason, not at every retry
                self.events.log.emit(NoPlanFound(news, result.proven, result.reason))
            self._want_plan(ReplanCause(ReplanReason.GOALS_WITHOUT_PLAN))
            self.progress = None
            return True
        self.events.plans += 1
        for name in request.goals:
            error = self.errors.pop(name, None)
            if error is not None:
                if self.op_state(name) is OperationState.ERROR:
                    self._set_op_state(name, OperationState.EXECUTING)
                if not error.livelock:  # it always had plans: its retry is no news
                    self.events.log.emit(PlanFound(name, error.attempts))
        # Measurements that arrived while planning are matched against the plan's trace
        # by the next tick, which asks again if the state has left it.
        self._follow(result)
        return True

    def _follow(self, plan: Plan) -> None:
        if plan.execution is None and self.progress is not None and self.progress.plan.execution is not None:
            # The rest of the plan under way, kept: it runs in the order it was checked in (controller/timed_check.py).
            plan = dataclasses.replace(plan, execution=self.progress.plan.execution)
        # What last set each device going is kept from plan to plan, so that a lost effect names its cause.
        self.progress = PlanProgress(self.compiled, plan, self._sent, self.engine.execution)

    def improve(self, request: PlanRequest, better: Plan, finish: FinishEstimate | None = None) -> bool:
        """A better plan for the request whose plan is under way (the portfolio kept searching): taken only while
        it is still valid from the measured state, and then only if the rest of it from there is shorter than
        what is left to do or, with `finish` (the predicted time a plan's steps not yet done take), no longer and
        faster by `FASTER_BY` at least."""
        progress = self.progress
        if (progress is None or self.planning or request.generation != self.generation
                or self.need_plan_reason is not None or set(progress.plan.goals) != set(better.goals)):
            return False
        left = sum(1 for _ in progress.pending())
        left_s = finish(progress.plan, frozenset(progress.done)) if finish is not None else None
        skip = set(self.op_index.values())  # operation states move on beside any plan
        here = tuple(v for i, v in enumerate(self.state) if i not in skip)
        for j, state in enumerate(better.states[:-1]):
            steps = len(better.steps) - j
            if steps > left or (steps == left and left_s is None):
                continue
            if tuple(v for i, v in enumerate(state) if i not in skip) != here:
                continue
            goals = {name: self.model.operation_by_name[name].goal for name in better.goals}
            kept = self.planner.revalidate(self.state, better.steps[j:], goals, self.disabled)
            if kept is None:
                continue
            taken: ShorterPlan | FasterPlan | None = None
            if len(kept.steps) < left:
                taken = ShorterPlan(len(kept.steps), left, better.stats.method)
            else:
                assert finish is not None and left_s is not None
                kept_s = finish(kept, frozenset())
                if kept_s < left_s * (1.0 - FASTER_BY):
                    taken = FasterPlan(len(kept.steps), round(kept_s, 3), round(left_s, 3), better.stats.method)
            if taken is not None:
                self._follow(kept)
                self.events.log.emit(taken)
                return True
        return False

    # --- the operator's interventions (controller/requests.py checks them first) ------------
    def withdraw(self, name: str, replan: ReplanCause | None = None) -> None:
        """Operation `name` back to `initial` and no longer requested; `replan` (why) drops the current
        plan, which was made for its goal too."""
        if name in self.requested:
            self.requested.remove(name)
        self.errors.pop(name, None)
        self._livelock_attempts.pop(name, None)
        self.livelock.finished()  # the operator starts afresh: no count from before holds
        self._set_op_state(name, OperationState.INITIAL)
        if replan is not None:
            self._want_plan(replan)

    def pause(self) -> None:
        self.paused = True

    def resume(self) -> None:
        # Devices went on while paused (automatic transitions and effects): the held plan's
        # trace may have been left in ways the engine cannot see, so plan afresh.
        self.paused = False
        self._want_plan(ReplanCause(ReplanReason.RESUMED))

    def force(self, path: str, value: Value, until: Callable[[State], bool] | None = None) -> None:
        i = self.compiled.index[path]
        held = self.forced.get(i)
        self.forced[i] = Force(value, held.own if held is not None else self.state[i], until)
        self.state = self.compiled.with_values(self.state, {path: value})
        self._blocks_changed()

    def unforce(self, path: str) -> bool:
        """Release a force; the variable takes its own value again. False if it was not forced."""
        held = self.forced.pop(self.compiled.index[path], None)
        if held is None:
            return False
        self.state = self.compiled.with_values(self.state, {path: held.own})
        self._blocks_changed()
        return True

    def own_state(self) -> State:
        """The state without the operator's forces: what is persisted, since a restart releases them."""
        if not self.forced:
            return self.state
        state = list(self.state)
        for i, held in self.forced.items():
            state[i] = held.own
        return tuple(state)

    def forced_paths(self) -> list[str]:
        return sorted(self.compiled.paths[i] for i in self.forced)

    def set_unknown(self, paths: Iterable[str]) -> None:
        """Command variables whose values the controller does not know (its resource is held): no transition
        and no operation start reading them fires, and no specification reading them is evaluated."""
        paths = list(paths)
        self.unknown = frozenset(self.compiled.index[p] for p in paths)
        self._blocks_changed()
        if self.listener is not None:
            self.listener.unknown_set(paths)

    def _blocks_changed(self) -> None:
        forced, unknown = set(self.forced), self.unknown
        self._blocked = frozenset(t.name for t in (*self.compiled.automatic, *self.compiled.deliberate)
                                  if t.writes & forced or t.reads & unknown)

    def _behind_forces(self, values: Mapping[str, Value]) -> tuple[dict[str, Value], dict[str, Value]]:
        """The measured values that no force hides, and the hidden ones that changed (kept as the
        variable's own value)."""
        index = self.compiled.index
        free, hidden = {}, {}
        for path, value in values.items():
            held = self.forced.get(index[path])
            if held is None:
                free[path] = value
            elif held.own != value:
                held.own = hidden[path] = value
        return free, hidden

    def _hold_forces(self) -> None:
        # Ability transitions that write a forced variable are blocked, but an operation's start and
        # finish actions are not: the force wins over them too.
        state = list(self.state)
        for i, held in self.forced.items():
            state[i] = held.value
        self.state = tuple(state)
        released = [self.compiled.paths[i] for i, held in self.forced.items()
                    if held.until is not None and held.until(self.state)]
        for path in released:
            self.unforce(path)
