"""The two-stage execution engine (DESIGN.md §4). Pure: no I/O, no clocks.

One tick takes the latest state (measured values from hubs, estimated and command
values owned by the controller) and returns the new state:

* **stage 1** — planning operations: finished operations (goal holds) become
  `finished` automatically; requested operations start when their precondition holds.
* **stage 2** — abilities: automatic transitions fire to a fixpoint; a deliberate
  transition fires only as a step of the current ability plan, once every earlier
  plan step it depends on has been observed, and only where its guard (synthesized
  guards included) holds. Effects are never applied here: they are observed.

Stage 1 then runs again (with the automatics its actions enable) until it changes
nothing: what stage 2 recorded may finish an operation or let a requested one start,
and the tick leaves no operation waiting for a state change that nothing will cause.

A plan is a shortest *sequence*, executed as a **partial order** (controller/deorder.py): a step
waits for the producers of what its guard needs, the earlier writers of what it writes, and the
consumers whose causal links it would break (threats); the operator mounts filters while the robot
tightens bolts. Safety does not rest on the order: a command fires only where its guard, the
supervisor's synthesized guard included, holds on the measured state at dispatch, so no forbidden
state is ever commanded. A step whose dependencies are done but whose guard fails waits; it asks for
a replan (STEP_BLOCKED) only once every step the former trace rule made it wait for is done. Every
dependency of either kind points to an earlier step of the sequence, so the earliest pending step
always has all of them done: it fires, is held for a due effect (bounded), or asks for a replan. No
deadlock. No needed effect is skipped silently: the values the engine expects are the last done
writers' (writers of one variable stay in order), and a step that overtook one whose condition it
took away (a threat the deordering judged wrongly) shows as a deviation from the expected values,
which asks for a replan with the reason, as a late effect does. The state must stay on the plan's
predicted values; when it leaves them, or when the next step can no longer fire, the tick asks for a
replan with the reason.

Effects take the time they take, and the measured state may be ahead of the plan's order: an
effect the plan lists after a command can already be due when the command is to be sent (the
vacuum holds before the robot has arrived). A command whose effect would overtake such an effect
of the plan is **held** until the effect has happened (`RaceCheck.overtaking`, the planner's race
test asked of the measured state); held longer than a bound derived from the effect's duration,
the tick asks for a replan naming the step and the effect. When the state leaves the plan because
an effect it needed lost its condition before it happened, the tick says which (`LostEffect`), so
that the controller can name it if the same thing happens again and again.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from operator import itemgetter

from common.config.modes import DEFAULT_EXECUTION
from common.model import Kind, TransitionKind, Value
from common.model.compiled import CompiledModel, CompiledTransition, State
from common.model.durations import effect_delays
from common.model.operations import RUNNING
from common.model.predicates import format_value
from common.wire.ctl import ReplanCause, ReplanReason

from .cycle import Waited, WaitKind
from .deorder import Execution, order
from .planner import Plan
from .planner.steps import RaceCheck

MAX_OPERATION_ROUNDS = 1000
# A held step waits at most this many times the longest duration of the effects it waits for: the effect
# was due before the hold began, and its news still has to come from the hub.
HOLD_BOUND_FACTOR = 2.0


def _reader(indices: tuple[int, ...]) -> Callable[[Sequence[Value]], object]:
    """The values at `indices` (a bare value for one index, as `itemgetter` returns it; () for none)."""
    if not indices:
        return lambda _state: ()
    return itemgetter(*indices)


class PlanProgress:
    """Which steps of an adopted plan have been fired or observed, and what state the plan predicts."""

    def __init__(self, compiled: CompiledModel, plan: Plan, sent: dict[str, str] | None = None,
                 execution: Execution = DEFAULT_EXECUTION) -> None:
        """`sent`: what last set each resource going (kept from the plan before, to name a lost effect's cause);
        `execution`: how steps wait for each other (hubs.toml's, by default the trace; controller/deorder.py)."""
        self.plan = plan
        self.execution = plan.execution or execution  # a plan the timed check ran in a stricter order keeps it
        self.transitions: list[CompiledTransition] = [compiled.by_name[s.transition] for s in plan.steps]
        self.post: list[tuple[tuple[int, Value], ...]] = [
            tuple((i, plan.states[j + 1][i]) for i in sorted(t.writes)) for j, t in enumerate(self.transitions)]
        # Each step's written values read at once (`observed` is asked of every step left at every tick).
        self._post_read = [_reader(tuple(i for i, _ in post)) for post in self.post]
        self._post_values = [_reader(tuple(range(len(post))))(tuple(v for _, v in post)) for post in self.post]
        self.reorder(compiled, self.execution)
        # The steps each stage looks at, in plan order: a tick walks them several times, and reading each
        # step's kind through its transition was a tenth of an in-process run.
        self.watched = tuple(j for j, t in enumerate(self.transitions) if t.kind is not TransitionKind.DELIBERATE)
        self.effect_steps = tuple(j for j, t in enumerate(self.transitions) if t.kind is TransitionKind.EFFECT)
        self.deliberate_steps = tuple(j for j, t in enumerate(self.transitions)
                                      if t.kind is TransitionKind.DELIBERATE)
        relevant: set[int] = set()
        for t in self.transitions:
            relevant |= t.reads | t.writes
        self.relevant = tuple(sorted(relevant))
        self.expected: dict[int, Value] = {i: plan.states[0][i] for i in self.relevant}
        self.done: set[int] = set()
        self.done_at: dict[int, float] = {}  # when each step was fired or observed (the tick's clock)
        self.ready_at: dict[int, float] = {}  # deliberate steps: when their dependencies were first all done
        self.guard_waits: set[int] = set()  # deliberate steps that waited, ready, for their guard
        self.held_since: dict[int, float] = {}  # deliberate steps held for a due effect, since when
        self.due: dict[int, State] = {}  # effect steps next in line, the last state where their guard held
        self.sent: dict[str, str] = {} if sent is None else sent  # resource -> the last command or automatic on it

    def reorder(self, compiled: CompiledModel, execution: Execution) -> None:
        """Steps wait for each other in `execution` from now on (the live controller's planner process found
        the plan under way safe in a looser order than the strictest it began in); what is done stays done."""
        self.execution = execution
        if self.plan.execution not in (None, execution):  # a kept rest of it runs in the same order
            self.plan = dataclasses.replace(self.plan, execution=execution)
        self.ordering = order(compiled, self.plan, execution)
        self.depends = self.ordering.depends
        self.prior_writers = self.ordering.prior_writers
        # Earlier automatic and effect steps that must see the old values of what a step writes.
        self.observers_before = self.ordering.observers_before

    @property
    def complete(self) -> bool:
        return len(self.done) == len(self.transitions)

    def ready(self, j: int) -> bool:
        return j not in self.done and self.depends[j] <= self.done

    def blocked_for_good(self, j: int) -> bool:
        """Step j's guard fails although every step the former trace rule made it wait for is done: no step
        the partial order let it overtake can still make it hold (see the module docstring)."""
        return self.ordering.trace[j] <= self.done

    def mark_done(self, j: int, now: float | None = None) -> None:
        self.done.add(j)
        if now is not None:
            self.done_at[j] = now
        for i, value in self.post[j]:
            self.expected[i] = value

    def observed(self, j: int, state: State) -> bool:
        """Every variable step j writes has the value it writes."""
        return bool(self._post_read[j](state) == self._post_values[j])

    def early(self, j: int, state: State) -> bool:
        """Step j (an effect or automatic) visibly happened before steps it was ordered after.

        Devices choose their own timing: the camera sees the operator enter the shared zone
        before the robot's next move that the plan put first. Every variable j writes has
        changed to j's value, and no step before it writes them. The commands it overtook are
        still sent only where their own guards (the supervisor's included) hold; if it overtook
        an automatic or effect step that needed the old values (the frame recorded lifted while
        the robot is still at the frame), that step will never happen: not early, a deviation.
        """
        post = self.post[j]
        return (bool(post) and self.prior_writers[j] <= self.done and self.observers_before[j] <= self.done
                and all(state[i] == v and self.expected[i] != v for i, v in post))

    def pending(self) -> Iterable[int]:
        return (j for j in range(len(self.transitions)) if j not in self.done)

    def next_step(self) -> int | None:
        return next(iter(self.pending()), None)

    def pending_effects(self) -> frozenset[int]:
        """The effect transitions (by number) the rest of the plan still needs."""
        return frozenset(self.transitions[j].number for j in self.pending()
                         if self.transitions[j].kind is TransitionKind.EFFECT)

    def note_due(self, state: State) -> None:
        """Remember, for each effect step whose predecessors are done, the last state in which it was enabled."""
        done = self.done
        for j in self.effect_steps:
            if j not in done and self.depends[j] <= done and self.transitions[j].guard(state):
                self.due[j] = state

    def lost_effect(self, compiled: CompiledModel, state: State) -> LostEffect | None:
        """An effect step that was due and lost its condition before it happened, and what took it away."""
        for j, when_due in sorted(self.due.items()):
            t = self.transitions[j]
            if j in self.done or t.guard(state) or self._moved_on(t, when_due, state):
                continue
            changed = [i for i in sorted(t.reads) if when_due[i] != state[i]]
            if not changed:
                continue
            i = changed[0]
            path = compiled.paths[i]
            after = self.sent.get(path.split(".", 1)[0])
            because = f"{path} left {format_value(when_due[i])} (now {format_value(state[i])})"
            return LostEffect(t.name, self.never_text(compiled, j), because + (f" after {after}" if after else ""))
        return None

    @staticmethod
    def _moved_on(t: CompiledTransition, when_due: State, state: State) -> bool:
        """The effect's device moved on: a value the effect writes is no longer what it was when the effect was
        due. The effect happened, with another of its outcomes than the plan's (a tightening that failed), or
        it and the device's next effect both came between two measurements (a move's start and its arrival,
        under load): not lost. A lost effect's own values stay; only what its guard reads was taken away."""
        return any(state[i] != when_due[i] for i in t.writes)

    def note_sent(self, compiled: CompiledModel, t: CompiledTransition, step: int | None) -> None:
        """A command or automatic transition fired (plan step `step`, if it is one): it set its resources going."""
        label = t.name if step is None else f"step {step} {t.name}"
        for i in t.writes:
            self.sent[compiled.paths[i].split(".", 1)[0]] = label

    def never_text(self, compiled: CompiledModel, j: int) -> str:
        became = ", ".join(f"{compiled.paths[i]} never became {format_value(v)}" for i, v in self.post[j])
        return f"{became or 'nothing changed'} ({self.transitions[j].name})"

    def waited_for(self, compiled: CompiledModel, j: int, now: float) -> Waited:
        """What deliberate step j, dispatched now, waited for last: its guard (a specification or the model's
        own), a due effect (a race hold), or the resource whose step was the last it depended on."""
        ready = self.ready_at.get(j, now)
        if ready < now:
            step = self.plan.steps[j]
            if j in self.held_since:
                return Waited(WaitKind.RACE_HOLD, step.transition)
            if j in self.guard_waits:
                held_by = ", ".join(step.held_by)
                return Waited(WaitKind.SPECIFICATION if held_by else WaitKind.GUARD, held_by or step.transition)
        timed = [d for d in self.depends[j] if d in self.done_at]
        if not timed:
            return Waited(WaitKind.PLAN, "")
        while True:
            last = max(timed, key=lambda d: (self.done_at[d], d))
            t = self.transitions[last]
            owner = compiled.model.resource_of(compiled.paths[min(t.writes)]) if t.writes else None
            if owner is not None:
                return Waited(WaitKind.RESOURCE, owner.name)
            # A tracking transition (the engine's record of a product) fires the moment its guard holds: the wait
            # was for the step that made it hold, a device's.
            timed = [d for d in self.depends[last] if d in self.done_at]
            if not timed:
                return Waited(WaitKind.GUARD, t.name)

    def deviation(self, compiled: CompiledModel, state: State) -> str | None:
        differing = [i for i in self.relevant if state[i] != self.expected[i]]
        if not differing:
            return None
        shown = "; ".join(f"{compiled.paths[i]} is {state[i]!r}, expected {self.expected[i]!r}" for i in differing[:4])
        more = f" and {len(differing) - 4} more" if len(differing) > 4 else ""
        return f"{shown}{more} (after {len(self.done)} of {len(self.transitions)} steps)"


@dataclass(frozen=True)
class Dispatched:
    """A plan step fired at this tick: a command to a resource, and what it had waited for."""

    step: int
    transition: str
    resources: frozenset[str]  # the resources whose commands it wrote
    waited: Waited


@dataclass(frozen=True)
class LostEffect:
    """An effect the plan needed that never happened: its condition was taken away first."""

    effect: str  # the effect transition
    never: str  # "f.present_m never became false (f.taken.effect)"
    because: str  # "r.pos_m left at_feeder (now unknown) after step 4 r.move_to_at_pallet.enabled"

    @property
    def text(self) -> str:
        return f"{self.never}: {self.because}"


@dataclass(frozen=True)
class HeldStep:
    """A plan step not sent yet: it would overtake an effect the plan needs that is due now."""

    step: int
    transition: str
    waits_for: str  # the effect transition


@dataclass
class TickResult:
    state: State
    fired: list[str] = field(default_factory=list)
    changed_commands: dict[str, Value] = field(default_factory=dict)
    started: list[str] = field(default_factory=list)
    finished: list[str] = field(default_factory=list)
    replan: ReplanCause | None = None  # why the current plan cannot be followed
    held: list[HeldStep] = field(default_factory=list)
    lost: LostEffect | None = None  # with `replan`: the effect whose loss took the state off the plan
    dispatched: list[Dispatched] = field(default_factory=list)  # the plan's commands fired


class Engine:
    def __init__(self, compiled: CompiledModel, delays: Mapping[str, float] | None = None,
                 execution: Execution = DEFAULT_EXECUTION) -> None:
        """`delays`: seconds each effect takes, by effect transition name (default: the model's,
        common/model/durations.py); they bound how long a step is held for a due effect. `execution`:
        how the plans this engine follows are ordered (`PlanProgress`)."""
        self.compiled = compiled
        self.execution = execution
        self.races = RaceCheck(compiled)  # every resource's effects: a disabled device may still act
        self.delays = dict(delays) if delays is not None else effect_delays(compiled.model)
        model = compiled.model
        self.operations = model.operations
        self.op_start = {op.name: compiled.by_name[f"{op.state_path}.start"] for op in model.operations}
        self.op_finish = {op.name: compiled.by_name[f"{op.state_path}.finish"] for op in model.operations}
        # An operation finishes only while running (its finish guard says so): a tick looks at the state's value
        # before the whole guard, which was a tenth of a production run with 45 operations mostly idle.
        self._finishing = tuple((compiled.index[op.state_path], op.name, self.op_finish[op.name])
                                for op in model.operations)
        self.command_indices = tuple(compiled.index[p] for p in model.paths_of_kind(Kind.COMMAND))
        # Tracking transitions (automatic, writing estimated variables only) are the controller's record
        # of what it observed; they command nothing, so an unhealthy resource does not hold them back.
        # Held back, the observation would be lost while the healthy devices go on (the nutrunner
        # resets after torque while the robot's hub is stale: the bolt is never recorded and is
        # tightened again).
        estimated = {compiled.index[p] for p in model.paths_of_kind(Kind.ESTIMATED)}
        self.tracking = frozenset(t.name for t in compiled.automatic if t.writes and t.writes <= estimated)

    def tick(
        self,
        state: State,
        *,
        requested: Sequence[str] = (),
        progress: PlanProgress | None = None,
        disabled: frozenset[str] = frozenset(),
        blocked: frozenset[str] = frozenset(),
        now: float | None = None,
    ) -> TickResult:
        """`disabled`: resources whose transitions do not fire (tracking excepted); `blocked`: ability
        transitions that do not fire (they write a variable the operator forced); `now`: the caller's
        clock, which bounds a held step (None: no bound)."""
        before = state
        result = TickResult(state)
        self._stage_operations(result, requested)
        self._stage_abilities(result, progress, disabled, blocked, now)
        # Stage 2's automatic transitions (tracking) may have made a goal or a requested operation's
        # precondition hold. Waiting for the next tick would wait for a state change that may never
        # come (nothing else is under way), so stage 1 runs again, with the automatics its start
        # and finish actions enable, until neither changes anything.
        held = self._held(disabled, blocked)
        for _ in range(MAX_OPERATION_ROUNDS):
            if not self._stage_operations(result, requested):
                break
            result.state, fired = self.compiled.close(result.state, held)
            result.fired += [t.name for t in fired]
        result.changed_commands = {
            self.compiled.paths[i]: result.state[i] for i in self.command_indices if result.state[i] != before[i]
        }
        return result

    # --- stage 1 ----------------------------------------------------------------------
    def _stage_operations(self, result: TickResult, requested: Sequence[str]) -> bool:
        """Finish and start operations until none does; True if any did."""
        any_progress = False
        for _ in range(MAX_OPERATION_ROUNDS):
            progressed = self._finish_operations(result)
            for name in requested:
                t = self.op_start[name]
                if t.guard(result.state):
                    result.state = t.outcomes[0](result.state)
                    result.fired.append(t.name)
                    result.started.append(name)
                    progressed = True
            if not progressed:
                break
            any_progress = True
        return any_progress

    def _finish_operations(self, result: TickResult) -> bool:
        progressed = False
        for index, name, t in self._finishing:
            if result.state[index] in RUNNING and t.guard(result.state):
                result.state = t.outcomes[0](result.state)
                result.fired.append(t.name)
                result.finished.append(name)
                progressed = True
        return progressed

    # --- stage 2 ----------------------------------------------------------------------
    def _held(self, disabled: frozenset[str],
              blocked: frozenset[str]) -> Callable[[CompiledTransition], bool] | None:
        """What holds an ability transition back: an unhealthy resource (tracking excepted) or a force."""
        if not disabled and not blocked:
            return None

        def is_disabled(t: CompiledTransition) -> bool:
            return (bool(t.resources & disabled) and t.name not in self.tracking) or t.name in blocked

        return is_disabled

    def _stage_abilities(self, result: TickResult, progress: PlanProgress | None, disabled: frozenset[str],
                         blocked: frozenset[str], now: float | None) -> None:
        held = self._held(disabled, blocked)

        def is_disabled(t: CompiledTransition) -> bool:
            return held is not None and held(t)

        state, fired = self.compiled.close(result.state, held)
        result.fired += [t.name for t in fired]
        if progress is not None:
            for t in fired:
                progress.note_sent(self.compiled, t, None)
            while True:
                self._observe(progress, state, now)
                deviation = progress.deviation(self.compiled, state)
                if deviation is not None:
                    result.replan = ReplanCause(ReplanReason.LEFT_PLAN, deviation)
                    result.lost = progress.lost_effect(self.compiled, state)
                    break
                progress.note_due(state)
                fired_one = False
                for j in progress.deliberate_steps:
                    t = progress.transitions[j]
                    if not progress.ready(j) or is_disabled(t):  # (a step done in this pass is not ready)
                        continue
                    if now is not None:
                        progress.ready_at.setdefault(j, now)
                    if not t.guard(state):
                        progress.guard_waits.add(j)
                        if progress.blocked_for_good(j):
                            result.replan = ReplanCause(ReplanReason.STEP_BLOCKED, str(progress.plan.steps[j]))
                            break
                        continue  # a step it may run beside (a supervisor's guard) still has to move on
                    if self._hold(result, progress, j, state, now):
                        if result.replan is not None:
                            break
                        continue
                    state = t.outcomes[0](state)
                    result.fired.append(t.name)
                    if now is not None:
                        written = frozenset(self.compiled.paths[i].split(".", 1)[0] for i in t.writes)
                        waited = progress.waited_for(self.compiled, j, now)
                        result.dispatched.append(Dispatched(j, t.name, written, waited))
                    progress.mark_done(j, now)
                    progress.note_sent(self.compiled, t, j)
                    state, autos = self.compiled.close(state, held)
                    result.fired += [a.name for a in autos]
                    for a in autos:
                        progress.note_sent(self.compiled, a, None)
                    fired_one = True
                if result.replan is not None or not fired_one:
                    break
        result.state = state

    def _hold(self, result: TickResult, progress: PlanProgress, j: int, state: State, now: float | None) -> bool:
        """Hold step j while it would overtake an effect the plan needs that is due on the measured state;
        past the bound, ask for a replan (`result.replan`). False: the step may fire."""
        t = progress.transitions[j]
        races = self.races.overtaking(state, t)
        if races:
            needed = progress.pending_effects()
            races = [race for race in races if race.due.number in needed]
        if not races:
            progress.held_since.pop(j, None)
            return False
        due = races[0].due
        result.held.append(HeldStep(j, t.name, due.name))
        if now is None:
            return True
        since = progress.held_since.setdefault(j, now)
        bound = HOLD_BOUND_FACTOR * max(self.delays.get(race.due.name, 0.0) for race in races)
        if now - since > bound:
            detail = (f"step {j} {t.name} held {now - since:.2f} s for {due.name}, "
                      f"which takes {self.delays.get(due.name, 0.0):.2f} s")
            result.replan = ReplanCause(ReplanReason.RACE_HOLD_EXPIRED, detail)
            k = next((k for k in progress.pending() if progress.transitions[k] is due), None)
            never = progress.never_text(self.compiled, k) if k is not None else due.name
            result.lost = LostEffect(due.name, never, f"step {j} {t.name} held {now - since:.2f} s for it")
        return True

    @staticmethod
    def _observe(progress: PlanProgress, state: State, now: float | None = None) -> None:
        """Mark effect and automatic steps done once their predecessors are done and their result shows."""
        done = progress.done
        left = [j for j in progress.watched if j not in done]
        changed = True
        while changed:
            changed = False
            for j in left:
                if j in done or not progress.observed(j, state):
                    continue
                if progress.ready(j) or progress.early(j, state):
                    progress.mark_done(j, now)
                    changed = True
