"""A plan's cycle time: when it should finish, and a lower bound no plan for its goals can beat (pure).

Time as the emulator has it (hubs/emulator.py): an effect happens its duration after its guard came to
hold (and stayed); commands and automatic transitions take no time.

* `predicted_finish`: every step of the plan starts as soon as the steps it depends on (the partial
  order, controller/deorder.py) have happened; the plan ends when its last step does.
* `lower_bound`: no execution of the plan's partial order is faster than the larger of
  - the **longest causal chain**: the durations along the longest path of causal links (a step and
    the producers of what its guard needs) that ends in a step the goals need;
  - the **busiest resource's necessary work**: the durations of that resource's effects the plan
    cannot do without (the goals need them, through causal links). A device does one thing at a time
    (its abilities' phases follow each other), so their durations add up.

A run's bound (`CycleRecord`, `CycleReport.bound`) is the largest of the run's longest causal chain, the
busiest resource's work over the run (the durations of its effects seen happen) and, once the run (or order) is
done, the work the specifications keep apart (controller/exclusions.py: intervals of different resources that
the supervisor's guards never let overlap, worked through one at a time). The chain
(controller/causal_chain.py) follows every transition the run saw happen, plan step or not: each starts
when the values its model guard reads were last written, and an effect takes its duration; the
supervisor's guards are left out there. All bound every schedule of the work the run did with the causes it
had, not every plan for the goals: a run that redoes work (a failed bolt) raises its own bound. Effects count
at their shortest (`shortest_seconds`): a device drawn faster than its longest must not beat the bound. The
first plan's bound is reported but not part of the run's: it bounds executions of that plan's order, and a
run that replans may end sooner. The goals of a station come in steps (an operation starts when its
precondition holds), so no single plan, not even the first, covers the cycle, and a bound from the start state
alone that ignores deletions is far too weak to judge a run by (4.7 s against 29 s on the reference station).

Durations come from `effect_seconds` and `shortest_seconds`, the one place they are read (common/model/durations.py).
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

from common.model import Model, TransitionKind, parse_predicate
from common.model.compiled import CompiledModel
from common.model.durations import Duration, effect_delays, effect_owner, effect_shortest

from .deorder import Ordering
from .exclusions import ExclusionBound
from .planner import Plan


def effect_seconds(model: Model, overrides: Mapping[str, Duration | float] | None = None) -> dict[str, float]:
    """Seconds each effect transition takes, by name: the durations table, read here only."""
    return effect_delays(model, overrides)


def shortest_seconds(model: Model, overrides: Mapping[str, Duration | float] | None = None) -> dict[str, float]:
    """Seconds each effect takes at the least, by name: what the bounds count (an effect drawn shorter than its
    longest must not make a run beat its bound)."""
    return effect_shortest(model, overrides)


def step_seconds(compiled: CompiledModel, plan: Plan, seconds: Mapping[str, float]) -> list[float]:
    return [seconds.get(step.transition, 0.0) if step.kind is TransitionKind.EFFECT else 0.0 for step in plan.steps]


def step_finishes(ordering: Ordering, durations: Sequence[float]) -> list[float]:
    """When each step happens if it starts as early as the steps it depends on allow."""
    finish: list[float] = []
    for j, duration in enumerate(durations):
        start = max((finish[d] for d in ordering.depends[j]), default=0.0)
        finish.append(start + duration)
    return finish


def predicted_finish(ordering: Ordering, durations: Sequence[float]) -> float:
    return max(step_finishes(ordering, durations), default=0.0)


class WaitKind(enum.Enum):
    """What a resource's next command waited for."""

    RESOURCE = "resource"  # a step of another (or the same) resource it depends on
    SPECIFICATION = "specification"  # the supervisor's guard for a specification
    GUARD = "guard"  # the model's own guard
    RACE_HOLD = "race hold"  # an effect the plan needs that the command would overtake
    PLAN = "plan"  # nothing in the plan: a plan, or an operation's start


@dataclass(frozen=True)
class Waited:
    kind: WaitKind
    what: str  # the resource, the specifications, the step

    @property
    def text(self) -> str:
        return f"{self.kind.value} {self.what}".strip()


@dataclass(frozen=True)
class Bound:
    seconds: float  # the lower bound: max(chain, busiest_work)
    chain: float  # the longest causal chain
    busiest: str  # the resource with the most necessary work ("" if none)
    busiest_work: float


def lower_bound(compiled: CompiledModel, plan: Plan, ordering: Ordering, durations: Sequence[float]) -> Bound:
    """No execution of `plan` reaches its goals sooner (see the module docstring)."""
    needed = _needed(compiled, plan, ordering)
    chain_at: list[float] = []
    for j, duration in enumerate(durations):
        chain_at.append(max((chain_at[p] for p in ordering.producers[j]), default=0.0) + duration)
    chain = max((chain_at[j] for j in needed), default=0.0)
    work: dict[str, float] = {}
    for j in sorted(needed):
        t = compiled.by_name[plan.steps[j].transition]
        if t.kind is TransitionKind.EFFECT and durations[j] > 0:
            owner = effect_owner(t.source)
            work[owner] = work.get(owner, 0.0) + durations[j]
    busiest = max(work, key=lambda r: (work[r], r), default="")
    busiest_work = work.get(busiest, 0.0)
    return Bound(max(chain, busiest_work), chain, busiest, busiest_work)


def _needed(compiled: CompiledModel, plan: Plan, ordering: Ordering) -> set[int]:
    """The steps the goals need: the last writers of what the goals read, and what they need in turn."""
    read = {compiled.index[p] for name in plan.goals for p in _goal_paths(compiled, name)}
    last: dict[int, int] = {}
    for j, step in enumerate(plan.steps):
        for i in compiled.by_name[step.transition].writes:
            last[i] = j
    needed: set[int] = set()
    stack = [last[i] for i in read if i in last] if read else list(range(len(plan.steps)))
    while stack:
        j = stack.pop()
        if j not in needed:
            needed.add(j)
            stack.extend(ordering.producers[j])
    return needed


def _goal_paths(compiled: CompiledModel, goal: str) -> set[str]:
    """The variables a plan goal reads: an operation's goal predicate, or the predicate itself."""
    operation = compiled.model.operation_by_name.get(goal)
    if operation is not None:
        return operation.goal.paths()
    try:
        return parse_predicate(goal).paths()
    except ValueError:
        return set()


@dataclass(frozen=True)
class ResourceIdle:
    resource: str
    idle: float  # seconds of the run it had nothing to do
    waits: tuple[tuple[str, float], ...]  # what its commands waited for (Waited.text), longest first

    @property
    def text(self) -> str:
        waited = ", ".join(f"{what} {seconds:.1f} s" for what, seconds in self.waits[:3])
        return f"{self.resource} idle {self.idle:.1f} s" + (f" (waited for {waited})" if waited else "")


@dataclass(frozen=True)
class CycleReport:
    cycle: float  # the run's time
    bound: float  # no schedule of the run's work ends sooner: the busiest resource's work, the run's chain
    predicted: float  # the predicted finish of the last plan
    idle: tuple[ResourceIdle, ...]
    first: Bound | None = None  # the first plan's bound
    busiest: str = ""  # the resource with the most work done (effects seen happen, at their durations)
    busiest_work: float = 0.0
    chain: float = 0.0  # the run's longest causal chain (controller/causal_chain.py), the first plan's included
    apart: float = 0.0  # the work the specifications keep apart, one interval after another (controller/exclusions.py)
    apart_resources: tuple[str, ...] = ()  # whose work that is

    @property
    def ratio(self) -> float:
        return self.cycle / self.bound if self.bound > 0 else 0.0

    def lines(self) -> list[str]:
        if self.apart > max(self.busiest_work, self.chain):
            made_of = (f"the work the specifications keep apart ({', '.join(self.apart_resources)}) "
                       f"{self.apart:.1f} s")
        elif self.busiest_work >= self.chain:
            made_of = f"busiest resource {self.busiest} {self.busiest_work:.1f} s of work"
        else:
            made_of = f"the run's longest causal chain {self.chain:.1f} s"
        return [f"cycle {self.cycle:.1f} s, bound {self.bound:.1f} s: {made_of}; cycle/bound {self.ratio:.2f}; "
                f"last plan predicted to end at {self.predicted:.1f} s",
                *(f"  {r.text}" for r in self.idle)]


class CycleRecord:
    """A run's plans' predictions and each resource's busy spans, as the loop saw them: a resource is busy
    from a command sent to it until the last change measured on it before the next command."""

    def __init__(self, resources: Sequence[str],
                 exclusions: Callable[[], ExclusionBound | None] | None = None) -> None:
        """`exclusions`: works out the bound from the specifications' exclusions over the run's log of transitions
        (controller/exclusions.py), asked only for a final report (`report(final=True)`)."""
        self.resources = list(resources)
        self.exclusions = exclusions
        self._apart: tuple[float, ExclusionBound | None] | None = None  # the end it was worked out for, and it
        self.predicted = 0.0  # absolute: the plan under way's predicted finish
        # Absolute: the first plan's bound, from when it was adopted. A later plan's bound, from its adoption,
        # follows the run itself (a replan late in the run is bounded by the run so far), so only the first
        # one says how close the run came to the best schedule of the work it was given.
        self.bound = 0.0
        self.first_bound: Bound | None = None
        self.work: dict[str, float] = {}  # each resource's effects seen happen, at their durations
        self.plan_bound: Bound | None = None  # the bound of the plan under way, from its adoption
        self.spans: dict[str, list[list[float]]] = {r: [] for r in self.resources}
        self.busy_let_go: dict[str, float] = {}  # the busy time of the spans let go (`forget_before`)
        self.waits: dict[str, dict[str, float]] = {r: {} for r in self.resources}
        self.chain = 0.0  # the run's longest causal chain (controller/causal_chain.py)

    def planned(self, now: float, predicted: float, bound: Bound) -> None:
        self.predicted = now + predicted
        self.plan_bound = bound
        if self.first_bound is None and bound.seconds > 0:
            # Reported, not taken into the run's bound: it bounds the executions of that plan's order, and a run
            # that replans may end sooner (2 of 40 random timed stations did).
            self.first_bound = bound

    def effect_done(self, resource: str, seconds: float) -> None:
        """An effect of `resource` seen happen: its duration is work that no schedule can overlap on it."""
        self.work[resource] = self.work.get(resource, 0.0) + seconds
        self.bound = max(self.bound, self.work[resource])

    def chained(self, longest: float) -> None:
        """The run's longest causal chain so far (controller/causal_chain.py, or the first plan's)."""
        self.chain = max(self.chain, longest)
        self.bound = max(self.bound, longest)

    def dispatched(self, now: float, resources: Iterable[str], waited: Waited) -> None:
        for r in resources:
            spans = self.spans.setdefault(r, [])
            gap = now - (spans[-1][1] if spans else 0.0)
            if gap > 0:
                waits = self.waits.setdefault(r, {})
                waits[waited.text] = waits.get(waited.text, 0.0) + gap
            if spans and spans[-1][1] >= now:
                continue
            spans.append([now, now])

    def measured(self, now: float, resources: Iterable[str]) -> None:
        for r in resources:
            spans = self.spans.get(r)
            if spans:
                spans[-1][1] = max(spans[-1][1], now)

    def forget_before(self, t: float) -> None:
        """Let go of the spans that ended before `t`, keeping their busy time: a station running orders needs
        an order's spans only until the order finished (controller/production/flow.py), and must not keep a
        shift's worth of them."""
        for r, spans in self.spans.items():
            old = 0
            while old < len(spans) - 1 and spans[old][1] < t:  # never the last: it may still grow
                old += 1
            if old:
                self.busy_let_go[r] = self.busy_let_go.get(r, 0.0) + sum(b - a for a, b in spans[:old])
                del spans[:old]

    def report(self, end: float, *, final: bool = False) -> CycleReport:
        """`final`: the run (or the order) is done: the bound takes in the specifications' exclusions (a second's
        work on a long run, done once for each end)."""
        apart: ExclusionBound | None = None
        if final and self.exclusions is not None:
            # Once per end: a finished station's statuses keep asking, and the log may still grow a little
            # (a camera, a hub's noise) without the run going on.
            if self._apart is None or self._apart[0] != end:
                self._apart = (end, self.exclusions())
            apart = self._apart[1]
        idle = []
        for r in self.resources:
            busy = self.busy_let_go.get(r, 0.0) + sum(b - a for a, b in self.spans.get(r, ()))
            waits = sorted(self.waits.get(r, {}).items(), key=lambda kv: -kv[1])
            idle.append(ResourceIdle(r, max(0.0, end - busy), tuple(waits)))
        busiest = max(self.work, key=lambda r: (self.work[r], r), default="")
        return CycleReport(end, max(self.bound, apart.seconds if apart is not None else 0.0), self.predicted,
                           tuple(idle), self.first_bound, busiest, self.work.get(busiest, 0.0), self.chain,
                           apart.seconds if apart is not None else 0.0, apart.resources if apart is not None else ())
