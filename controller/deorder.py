"""A plan's steps as a partial order: causal links and threats, not shared variables (DESIGN.md §4).

A plan is a shortest *sequence*; the engine (controller/engine.py) executes it as a partial order,
so that the operator mounts the filters while the robot tightens the bolts. Step k needs:

* **its producers**: for each variable its guard reads, the earliest writer w_t of the chain of
  earlier writers w_1 < … < w_m of that variable (in plan order) such that every value from w_t's
  on (v_t … v_m) satisfies k's guard, all other variables as the plan has them before k. The
  need is judged on the guard's predicate, not on the variables it mentions: the robot's last move
  does not produce `ur.pos_m != at_filter` unless the value before it violated that. A value an
  outcome copies (`x := y`) is needed exactly: its last writer is its producer;
* **its write order**: the last earlier writer of each variable it writes, so that the values the
  engine expects (the last done writer's) are the ones the devices show;
* **its threats**: a later step j that writes a value falsifying k's guard (or changing a value k
  copies) is ordered after k. An effect or automatic cannot be held back, so the nearest deliberate
  steps it descends from (through producers and write order) that come after k in the plan are
  ordered after k as well: a command is what sets a device going. One that comes before k sets the
  threat going before k can fire, so it waits for k's other producers: k then fires as soon as the
  command's device gives it the rest (a tracking step that needs a transient value).

Every dependency points to an earlier step of the sequence, so the order is acyclic. `trace` keeps
the former rule (a step waits for every earlier step it shares a variable with, and a command for
every earlier reader of its device): the engine falls back on it for a step whose guard does not hold
(see engine.py), and the cycle benchmark runs it as "before". `Execution.SEQUENCE` waits for every earlier
step: a plan that a timing of its effects breaks in the other two orders (controller/timed_check.py) runs so.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

from common.model import TransitionKind, Value
from common.model.compiled import CompiledModel, CompiledTransition, State
from common.model.predicates import Ref

from .planner import Plan
from .planner.plans import Execution, PlanStep

__all__ = ["Execution", "Ordering", "copied_reads", "order"]


@dataclass(frozen=True)
class Ordering:
    """What each step of a plan waits for, by step number."""

    depends: tuple[frozenset[int], ...]  # the steps that must have happened before it
    producers: tuple[frozenset[int], ...]  # of `depends`, the causal links: the steps that made its guard hold
    trace: tuple[frozenset[int], ...]  # the former rule's dependencies (a superset of a valid order's needs)
    prior_writers: tuple[frozenset[int], ...]  # the last earlier step writing each variable it writes
    observers_before: tuple[frozenset[int], ...]  # earlier automatic and effect steps reading what it writes


def copied_reads(t: CompiledTransition, index: dict[str, int]) -> frozenset[int]:
    """The variables whose values an outcome of `t` copies: needed exactly, not only as the guard judges."""
    return frozenset(index[a.value.path] for outcome in t.source.outcomes for a in outcome if isinstance(a.value, Ref))


def _with(state: State, i: int, value: Value) -> State:
    as_list = list(state)
    as_list[i] = value
    return tuple(as_list)


class _GuardTest:
    """k's guard with one variable changed, memoized by value (domains are small, chains are long)."""

    def __init__(self, guard: Callable[[State], bool], before: State) -> None:
        self.guard, self.before = guard, before
        self.memo: dict[tuple[int, Value], bool] = {}

    def holds_with(self, i: int, value: Value) -> bool:
        key = (i, value)
        if key not in self.memo:
            self.memo[key] = value == self.before[i] or self.guard(_with(self.before, i, value))
        return self.memo[key]


ORDERINGS_KEPT = 256  # a station's plans in use at once, and those its planner remembers for the next orders


def order(compiled: CompiledModel, plan: Plan, execution: Execution = Execution.PARTIAL_ORDER) -> Ordering:
    """What each step of `plan` waits for in `execution`. Remembered: the engine orders every plan it follows,
    every rest of one it keeps and every plan the timed check simulates, and the planner hands back the same
    plans order after order; ordering a 233-step plan afresh each time was half of an in-process run's CPU."""
    return _remembered(compiled, plan.steps, plan.states, execution)


@functools.lru_cache(maxsize=ORDERINGS_KEPT)
def _remembered(compiled: CompiledModel, steps: tuple[PlanStep, ...], states: tuple[State, ...],
                execution: Execution) -> Ordering:
    return _order(compiled, steps, states, execution)


def _order(compiled: CompiledModel, steps: tuple[PlanStep, ...], states: tuple[State, ...],
           execution: Execution) -> Ordering:
    transitions = [compiled.by_name[s.transition] for s in steps]
    trace, prior_writers, observers_before = _trace_order(compiled, transitions)
    if execution is Execution.TRACE:
        return Ordering(trace, trace, trace, prior_writers, observers_before)
    if execution is Execution.SEQUENCE:
        sequence = tuple(t | {j - 1} if j else t for j, t in enumerate(trace))
        return Ordering(sequence, trace, trace, prior_writers, observers_before)
    writers: dict[int, list[int]] = {}  # variable -> the steps writing it, in plan order
    for j, t in enumerate(transitions):
        for i in t.writes:
            writers.setdefault(i, []).append(j)
    producers: list[set[int]] = []
    tests = [_GuardTest(t.guard, states[k]) for k, t in enumerate(transitions)]
    exact = [copied_reads(t, compiled.index) for t in transitions]
    for k, t in enumerate(transitions):
        needs: set[int] = set()
        for i in t.reads:
            chain = writers.get(i, ())
            before_k = [w for w in chain if w < k]
            if not before_k:
                continue
            if i in exact[k]:
                needs.add(before_k[-1])
                continue
            producer = _earliest_sufficient(tests[k], i, before_k, states)
            if producer is not None:
                needs.add(producer)
        producers.append(needs)
    base = [set(producers[j]) | set(prior_writers[j]) for j in range(len(transitions))]
    threatened: list[set[int]] = [set() for _ in transitions]  # j -> the consumers it must follow
    for k, t in enumerate(transitions):
        for i in t.reads:
            for j in writers.get(i, ()):
                if j <= k:
                    continue
                value = states[j + 1][i]
                if (value != states[k][i]) if i in exact[k] else not tests[k].holds_with(i, value):
                    threatened[j].add(k)
                    break  # later writers of i follow j (write order)
    depends = [set(b) for b in base]
    for j, consumers in enumerate(threatened):
        if not consumers:
            continue
        depends[j] |= consumers
        if transitions[j].kind is not TransitionKind.DELIBERATE:
            for d in _nearest_deliberate(j, base, transitions):
                depends[d] |= {k for k in consumers if k < d}
                # d sets j off before k: nothing can hold j back once d is sent (the nutrunner resets itself
                # after torque), so k must be able to fire as soon as d's device gives it what it needs. d
                # therefore waits for k's other producers (the operator instructed to tighten pipe 2 before
                # the nutrunner runs, or its torque is never recorded for pipe 2).
                for k in consumers:
                    if d < k:
                        depends[d] |= {p for p in producers[k] if p < d}
    for j in range(len(transitions)):
        depends[j].discard(j)
    return Ordering(tuple(frozenset(d) for d in depends), tuple(frozenset(p) for p in producers), trace,
                    prior_writers, observers_before)


def _earliest_sufficient(test: _GuardTest, i: int, chain: Sequence[int], states: Sequence[State]) -> int | None:
    """The earliest writer in `chain` from whose value on every later one satisfies the guard (None: even the
    value before the first does)."""
    for n in range(len(chain) - 1, -1, -1):
        value_before = states[chain[n]][i]
        if not test.holds_with(i, value_before):
            return chain[n]
    return None


def _nearest_deliberate(j: int, base: Sequence[set[int]], transitions: Sequence[CompiledTransition]) -> set[int]:
    """The deliberate steps effect or automatic step j descends from, not looking past a deliberate one."""
    found: set[int] = set()
    seen: set[int] = set()
    stack = list(base[j])
    while stack:
        d = stack.pop()
        if d in seen:
            continue
        seen.add(d)
        if transitions[d].kind is TransitionKind.DELIBERATE:
            found.add(d)
        else:
            stack.extend(base[d])
    return found


def _trace_order(compiled: CompiledModel, transitions: Iterable[CompiledTransition]) -> tuple[
        tuple[frozenset[int], ...], tuple[frozenset[int], ...], tuple[frozenset[int], ...]]:
    """The former rule: a step waits for the earlier steps it shares a variable with."""
    depends: list[frozenset[int]] = []
    prior_writers: list[frozenset[int]] = []
    observers_before: list[frozenset[int]] = []
    kinds: list[TransitionKind] = []
    last_writer: dict[int, int] = {}
    readers_since_write: dict[int, list[int]] = {}
    # A command sets its device going: the device's measured state changes later, by effects the
    # plan lists further on. So a deliberate step waits for every earlier step that reads the
    # device, not only for those that read what the step itself writes.
    readers_of_resource: dict[str, list[int]] = {}
    resource_of = [path.split(".", 1)[0] for path in compiled.paths]
    for j, t in enumerate(transitions):
        kinds.append(t.kind)
        deps: set[int] = {last_writer[i] for i in t.reads | t.writes if i in last_writer}
        if t.kind is TransitionKind.DELIBERATE:
            for resource in {resource_of[i] for i in t.writes}:
                deps.update(readers_of_resource.get(resource, ()))
        for resource in {resource_of[i] for i in t.reads}:
            readers_of_resource.setdefault(resource, []).append(j)
        prior_writers.append(frozenset(last_writer[i] for i in t.writes if i in last_writer))
        observers_before.append(frozenset(k for i in t.writes for k in readers_since_write.get(i, ())
                                          if kinds[k] is not TransitionKind.DELIBERATE))
        for i in t.writes:
            deps.update(readers_since_write.get(i, ()))
            readers_since_write[i] = []
            last_writer[i] = j
        for i in t.reads - t.writes:
            readers_since_write.setdefault(i, []).append(j)
        deps.discard(j)
        depends.append(frozenset(deps))
    return tuple(depends), tuple(prior_writers), tuple(observers_before)
