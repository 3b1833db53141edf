"""Plans checked in time before use (issue 21, item 2; DESIGN.md §4).

A plan is a sequence the planner found without time: it may count on an enabled effect waiting for it
(the nutrunner's reset while a slow operator confirms pipe 1, so that pipe 2 is recorded on pipe 1's
torque). The devices do not wait. `TimedCheck` runs the plan as the engine would dispatch it
(controller/engine.py, the same `Engine` and `PlanProgress`, with the plan's `Execution`) against the
emulator's semantics (hubs/emulator.py: an effect is scheduled when its guard starts to hold, fires
after its duration unless its guard failed meanwhile, with no regard for the plan), in virtual time, at
the corners of the effects' intervals: every effect at its earliest, every one at its latest, and each
resource's effects at one end while every other's are at the other. Those are the timings that matter:
an effect due while a later step takes its condition away comes out at one of them.

A plan the engine would not follow to its end at one of them (it leaves the plan, a step can no longer
fire, a held step waits too long, or nothing more can happen) is refused with a `TimingRefusal` that
names the effect whose timing broke it, the plan step concerned, and the timing.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import operator
from collections import OrderedDict
from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass

from common.config.modes import DEFAULT_EXECUTION
from common.model import Duration, Predicate, TransitionKind
from common.model.compiled import CompiledModel, CompiledTransition, State
from common.model.durations import duration_in, effect_owner
from common.wire.ctl import ReplanReason

from .deorder import Execution
from .engine import Engine, PlanProgress, TickResult
from .planner import Plan, Planner
from .planner.plans import PlanStep
from .planner.reuse import memory_key

TICKS_AT_ONCE = 100  # engine ticks at one instant before the devices get their turn (as deploy/local/inprocess.py)
MAX_EVENTS = 20_000  # instants simulated before a plan is given up as never ending
MAX_KEPT = 200  # plans kept from a state they did not predict (`Revalidate`) in one simulation
CHECKS_KEPT = 512  # plans' verdicts remembered: in production the same plans come back from the same states
STOP_EVERY = 64  # instants simulated between two looks at `stop` (a newer request waiting, in the planner process)
# A plan the engine's own order breaks at some timing runs in the first stricter order none breaks.
STRICTER = {
    Execution.PARTIAL_ORDER: (Execution.TRACE, Execution.SEQUENCE),
    Execution.TRACE: (Execution.SEQUENCE,),
    Execution.SEQUENCE: (),
}
STRICTEST = Execution.SEQUENCE  # what a plan runs in until its check says a looser order is safe

# The rest of a plan replayed from a state it did not predict (the controller's `Planner.revalidate` for the
# plan's goals): the plan to go on with, or None. The live controller keeps a plan so when devices change
# what no step waits for (the camera sees the operator step out); the simulation does the same.
Revalidate = Callable[[State, Sequence[PlanStep]], Plan | None]


class TimingFault(enum.Enum):
    """How a plan failed at a timing."""

    LEFT_PLAN = "the state left the plan"  # an effect came before a step that needed what it changed
    STEP_BLOCKED = "a step can no longer fire"
    HOLD_EXPIRED = "a step held for a due effect waited longer than the effect takes"
    STUCK = "nothing more can happen"  # the plan waits for an effect that is not enabled
    GOALS_NOT_REACHED = "the plan ends but its goals do not hold"


_FAULTS = {
    ReplanReason.LEFT_PLAN: TimingFault.LEFT_PLAN,
    ReplanReason.STEP_BLOCKED: TimingFault.STEP_BLOCKED,
    ReplanReason.RACE_HOLD_EXPIRED: TimingFault.HOLD_EXPIRED,
}


@dataclass(frozen=True)
class Timing:
    """One corner of the effects' intervals: the seconds each effect takes, by transition name."""

    name: str  # "every effect at its earliest", "human's effects at their latest, the others' at their earliest"
    seconds: Mapping[str, float]


@dataclass(frozen=True)
class TimingRefusal:
    """Why a plan is refused: at `timing`, effect `effect` broke plan step `step` (`transition`)."""

    fault: TimingFault
    effect: str  # the effect whose timing broke the plan ("" when none is to blame: a step blocked, stuck)
    step: int  # the plan step that could not be followed (its index in the plan)
    transition: str  # that step's transition
    timing: str  # Timing.name
    at: float  # station seconds after the plan's start
    detail: str  # what the engine said

    @property
    def text(self) -> str:
        blame = f"{self.effect} came first: " if self.effect else ""
        return (f"{blame}step {self.step} {self.transition}: {self.fault.value} at {self.at:.2f} s "
                f"with {self.timing} ({self.detail})")


class CheckStopped(Exception):
    """The check was asked to stop (`stop()` said so) before it had its verdict."""


@dataclass(frozen=True)
class Verdict:
    """A plan checked in time: `plan` with the order it runs in (the engine's own if no timing breaks it there,
    else the first stricter one none breaks, else the strictest), and the timings that broke it in the orders
    tried. `passed`: some order passed; if not, the last refusal is the race the plan itself counts on."""

    plan: Plan
    refusals: tuple[TimingRefusal, ...]
    passed: bool

    @property
    def refusal(self) -> TimingRefusal | None:
        """The race the plan loses in every order (None: it passed in one)."""
        return None if self.passed else self.refusals[-1]


@dataclass(frozen=True, eq=False)
class Revalidation:
    """How the controller keeps a plan from a state it did not predict: `Planner.revalidate` for the plan's goals.
    Its answers depend on nothing but its arguments and the races the planner has learnt (`key`), so a check that
    used it can be remembered."""

    planner: Planner
    goals: Mapping[str, Predicate]
    disabled: frozenset[str]

    def __call__(self, state: State, steps: Sequence[PlanStep]) -> Plan | None:
        return self.planner.revalidate(state, steps, self.goals, self.disabled)

    def key(self) -> Hashable:
        return frozenset(self.goals), self.disabled, self.planner.timed_races.version


def revalidation(planner: Planner, operation_goals: Mapping[str, Predicate], plan: Plan,
                 disabled: frozenset[str]) -> Revalidation | None:
    """How the controller keeps `plan` from a state it did not predict (`Planner.revalidate` for its goals)."""
    goals = {name: operation_goals[name] for name in plan.goals if name in operation_goals}
    if not goals:
        return None
    return Revalidation(planner, goals, disabled)


def learn_race(planner: Planner, compiled: CompiledModel, refused: TimingRefusal, goals: Mapping[str, Predicate],
               disabled: frozenset[str]) -> bool:
    """Forbid the race a refused plan lost for the planning to come (and forget the plan remembered for these
    goals, the refused one); False if nothing new is learnt."""
    victim, due = compiled.by_name.get(refused.transition), compiled.by_name.get(refused.effect)
    if victim is None or due is None or victim.kind is TransitionKind.AUTOMATIC:
        return False
    if not planner.timed_races.forbid(victim, due):
        return False
    planner.memory.forget(memory_key(goals, disabled))
    return True


def corner_timings(compiled: CompiledModel, durations: Mapping[str, Duration]) -> list[Timing]:
    """The timings a plan is checked at: all earliest, all latest, and each resource with an interval at one
    end while the others are at the other. Fixed durations give one timing."""
    owner = {t.name: effect_owner(t.source) for t in compiled.effects if t.writes}
    taking = {name: duration_in(durations, name, r) for name, r in owner.items()}

    def seconds(pick: Callable[[str], bool]) -> dict[str, float]:
        """`pick(resource)`: True for its earliest."""
        return {name: taking[name].min_s if pick(r) else taking[name].max_s for name, r in owner.items()}

    timings = [Timing("every effect at its earliest", seconds(lambda _r: True)),
               Timing("every effect at its latest", seconds(lambda _r: False))]
    varying = sorted({r for name, r in owner.items() if not taking[name].is_fixed})
    for r in varying:
        timings.append(Timing(f"{r}'s effects at their earliest, the others' at their latest",
                              seconds(functools.partial(operator.eq, r))))
        timings.append(Timing(f"{r}'s effects at their latest, the others' at their earliest",
                              seconds(functools.partial(operator.ne, r))))
    unique: dict[tuple[tuple[str, float], ...], Timing] = {}
    for timing in timings:
        unique.setdefault(tuple(sorted(timing.seconds.items())), timing)
    return list(unique.values())


class _Devices:
    """The emulator's semantics on compiled states: an effect fires its duration after its guard began to
    hold, unless the guard failed meanwhile. The outcome is the one the plan's next step of it expects."""

    def __init__(self, effects: tuple[CompiledTransition, ...], seconds: Mapping[str, float]) -> None:
        self.effects = effects
        self.seconds = seconds
        self.due: dict[int, float] = {}  # effect number -> when it fires

    def step(self, state: State, now: float, outcome_of: Callable[[CompiledTransition], int]
             ) -> tuple[State, list[CompiledTransition]]:
        fired: list[CompiledTransition] = []
        for t in self.effects:
            if not t.guard(state):
                self.due.pop(t.number, None)
                continue
            due = self.due.get(t.number)
            if due is None:
                self.due[t.number] = now + self.seconds.get(t.name, 0.0)
            elif due <= now:
                del self.due[t.number]
                state = t.outcomes[outcome_of(t)](state)
                fired.append(t)
        return state, fired

    def next_due(self) -> float | None:
        return min(self.due.values(), default=None)


def _check_key(plan: Plan, disabled: frozenset[str], execution: Execution,
               revalidate: Revalidate | None) -> Hashable | None:
    """What a check's answer depends on; None where that is not known (a revalidation other than the planner's)."""
    if revalidate is not None and not isinstance(revalidate, Revalidation):
        return None
    kept = None if revalidate is None else revalidate.key()
    return plan.steps, plan.states[0], plan.execution, disabled, execution, kept


class TimedCheck:
    """Checks plans against the corner timings of one station's effect durations."""

    def __init__(self, compiled: CompiledModel, durations: Mapping[str, Duration],
                 execution: Execution = DEFAULT_EXECUTION, kept: int | None = None) -> None:
        """`durations`: each resource's interval, and the effects' with their ability's own
        (common/model/durations.py's `DurationTable.keyed()`); `kept`: verdicts remembered (default
        `CHECKS_KEPT`; 0: none)."""
        self.compiled = compiled
        self.execution = execution
        self.timings = corner_timings(compiled, durations)
        self.delays = {name: max(t.seconds.get(name, 0.0) for t in self.timings)
                       for name in (e.name for e in compiled.effects)}
        self._engine = Engine(compiled, self.delays, execution)
        self.kept = CHECKS_KEPT if kept is None else kept
        self._checks: OrderedDict[Hashable, TimingRefusal | None] = OrderedDict()

    def refusal(self, plan: Plan, disabled: frozenset[str] = frozenset(), execution: Execution | None = None,
                revalidate: Revalidate | None = None, stop: Callable[[], bool] | None = None
                ) -> TimingRefusal | None:
        """Why the engine would not follow `plan` at one of the timings (None: it would at every one).
        `execution`: how its steps wait for each other (default: this check's); `revalidate`: how the
        controller keeps a plan when the state leaves it (None: it does not); `stop`: looked at as the
        simulation goes, raises `CheckStopped` when it says so."""
        if not plan.steps:
            return None
        execution = execution or self.execution
        key = _check_key(plan, disabled, execution, revalidate)
        if key in self._checks:
            self._checks.move_to_end(key)
            return self._checks[key]
        self._engine.execution = execution
        refused = next((r for r in (self._run(plan, disabled, timing, revalidate, stop) for timing in self.timings)
                        if r is not None), None)
        if key is not None and self.kept > 0:  # (a check that `stop` cut short raised: nothing is remembered)
            self._checks[key] = refused
            while len(self._checks) > self.kept:
                self._checks.popitem(last=False)
        return refused

    def verdict(self, plan: Plan, disabled: frozenset[str] = frozenset(), revalidate: Revalidate | None = None,
                stop: Callable[[], bool] | None = None, *, own: Execution | None = None,
                stricter: bool = True) -> Verdict:
        """`plan` in the engine's order (`own`, default: this check's) if no timing breaks it there, else
        (`stricter`) in the first stricter order none breaks (the nutrunner started only once the operator is told
        to tighten pipe 2), else in the strictest, refused."""
        own = own or self.execution
        refusals: list[TimingRefusal] = []
        for execution in (own, *(STRICTER[own] if stricter else ())):
            refused = self.refusal(plan, disabled, execution, revalidate, stop)
            if refused is None:
                return Verdict(dataclasses.replace(plan, execution=execution), tuple(refusals), passed=True)
            refusals.append(refused)
        return Verdict(dataclasses.replace(plan, execution=STRICTEST), tuple(refusals), passed=False)

    def _run(self, plan: Plan, disabled: frozenset[str], timing: Timing,
             revalidate: Revalidate | None, stop: Callable[[], bool] | None) -> TimingRefusal | None:
        compiled = self.compiled
        engine = self._engine
        progress = PlanProgress(compiled, plan, execution=engine.execution)
        effects = tuple(e for e in compiled.effects if e.writes and not (e.resources & disabled))
        devices = _Devices(effects, timing.seconds)
        state = plan.states[0]
        now = 0.0
        last_fired: list[CompiledTransition] = []
        kept = 0

        def outcome_of(t: CompiledTransition) -> int:
            step = next((j for j in progress.pending() if progress.transitions[j] is t), None)
            return 0 if step is None else plan.steps[step].outcome

        for instant in range(MAX_EVENTS):
            if stop is not None and instant % STOP_EVERY == 0 and stop():
                raise CheckStopped
            for _tick in range(TICKS_AT_ONCE):
                before = state
                result = engine.tick(state, progress=progress, disabled=disabled, now=now)
                state = result.state
                if result.replan is not None:
                    again = None
                    if (revalidate is not None and kept < MAX_KEPT
                            and result.replan.reason is ReplanReason.LEFT_PLAN):
                        kept += 1
                        again = revalidate(state, [progress.plan.steps[j] for j in sorted(progress.pending())])
                    if again is None:
                        return self._refused(progress, result, last_fired, timing, now)
                    progress = PlanProgress(compiled, again, progress.sent, engine.execution)
                    plan = again
                    continue
                if progress.complete or state == before:
                    break
            if progress.complete:
                return None
            state, fired = devices.step(state, now, outcome_of)
            if fired:
                last_fired = fired
                continue
            due = devices.next_due()
            if due is None:
                j = progress.next_step()
                assert j is not None  # the plan is not complete
                return TimingRefusal(TimingFault.STUCK, "", j, plan.steps[j].transition, timing.name, now,
                                     f"waiting for {progress.never_text(compiled, j)}")
            now = max(now, due)
        j = progress.next_step() or 0
        return TimingRefusal(TimingFault.STUCK, "", j, plan.steps[j].transition, timing.name, now,
                             f"no end after {MAX_EVENTS} instants")

    def _refused(self, progress: PlanProgress, result: TickResult, last_fired: list[CompiledTransition],
                 timing: Timing, now: float) -> TimingRefusal:
        """The refusal for the engine's replan: the effect to blame and the step it broke."""
        assert result.replan is not None
        fault = _FAULTS.get(result.replan.reason, TimingFault.LEFT_PLAN)
        effect = result.lost.effect if result.lost is not None else ""
        victim: int | None = None
        if not effect and fault is TimingFault.LEFT_PLAN:
            # The effect that just fired out of the plan's order, and the first pending step that needed what
            # it changed (the tracking of pipe 2 that needed the nutrunner's torque the reset took away). Of
            # several that fired at once, one that wrote a value the plan did not expect is to blame first: the
            # nutrunner back in its dock, not the camera that saw the operator step out at the same moment (a race
            # learnt against the camera sent the planner round through pipe 1's instruction again and again).
            differing = {i for i in progress.relevant if result.state[i] != progress.expected[i]}
            for e in sorted(last_fired, key=lambda fired: not (fired.writes & differing)):
                changed = e.writes
                reader = next((j for j in progress.pending()
                               if progress.transitions[j] is not e and progress.transitions[j].reads & changed), None)
                if reader is not None:
                    effect, victim = e.name, reader
                    break
        if victim is None:
            held = next((h for h in result.held), None)
            if held is not None and fault is TimingFault.HOLD_EXPIRED:
                victim = held.step
            elif effect:
                victim = next((j for j in progress.pending() if progress.transitions[j].name == effect), None)
        if victim is None:
            victim = progress.next_step() or 0
        detail = result.replan.detail
        if result.lost is not None:
            detail = result.lost.text
        return TimingRefusal(fault, effect, victim, progress.plan.steps[victim].transition, timing.name, now, detail)
