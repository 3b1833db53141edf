"""The specifications' exclusions in a run's bound: work the supervisor keeps apart adds up (issue 21).

The run's causal chain (controller/causal_chain.py) bounds every schedule of the run's work with the same causes,
but lets two devices work at once wherever no cause orders them: the robot moving while the nutrunner it holds
runs, which a specification forbids. This module bounds the same schedules, now also kept to the supervisor's
guards, by adding up the durations of work that cannot overlap in any of them.

**The schedules.** Every transition the run saw happen happens once (`RunLog`); each reads every variable its
model guard and actions read from the same transition as in the run (its *cause*; none before it: the window's
start); an effect happens at least its duration after its cause; and a command fires only when its whole guard,
the supervisor's part included, holds.

**What follows for every such schedule** (`_Order`): a transition comes after its causes; and after every
transition that read a variable from a writer the transition comes after (were it earlier, it would be the
reader's last writer instead). A variable's value at a transition x is known when its last writer W before x
in the run comes before x and some transition reading it from W comes at or after x: nothing writes it
between (`pinned`).

**Work that cannot overlap.** A resource's *interval* runs from one of its commands through the transitions of
the same resource that follow it, up to its next command, when they follow one another in every schedule and
the resource's other transitions come before or after them all; the resource's own variables then pass through
the same values inside it in every schedule. Two intervals of different resources cannot overlap when neither
command can fire inside the other: its guard, evaluated with the values pinned at the command and each value the
other resource passes through there (anything else unknown, three-valued), is false. Of two overlapping
intervals one's command would lie inside the other, so such intervals follow one another, in one order or the
other. An interval lasts at least the longest path of durations from its command to its end.

**The bound.** A set of intervals that pairwise cannot overlap is worked through one at a time: no schedule ends
before, for the intervals K that start no earlier than a given one, the earliest start among them, plus their
durations, plus the least time left after any of them (the one-machine bound, `_one_machine`). The set is found
greedily, from each resource's intervals, and improved by exchanges (an interval in for those it overlaps, when
the bound grows: `_kept_apart`); any such set gives a bound, so the search only decides how tight it is.

A change that no transition explains (a restarted hub) is a transition without causes: it only weakens the
bound. The log keeps at most `MAX_EVENTS` transitions; a longer window has no bound from here.
"""

from __future__ import annotations

import bisect
import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from common.model import TransitionKind, Value
from common.model.compiled import CompiledModel, CompiledTransition, State
from common.model.durations import writer_owner
from common.model.predicates import And, Const, Eq, In, IsTrue, Ne, Not, Or, Predicate, Ref

MAX_EVENTS = 6_000  # transitions in one window (a reference cycle has about 500)
EXCHANGE_PASSES = 4  # rounds of exchanges in the search for a set of intervals


class Unknown:
    """A value not known at a moment: predicates over it may be neither true nor false."""


UNKNOWN = Unknown()


def partly(predicate: Predicate, values: Mapping[str, Value | Unknown]) -> bool | None:
    """The predicate under values some of which are unknown (absent or UNKNOWN): True or False when every
    completion agrees, None otherwise (Kleene's three-valued logic)."""
    p = predicate
    if isinstance(p, Const):
        return p.value
    if isinstance(p, IsTrue):
        return partly(Eq(p.path, True), values)
    if isinstance(p, Eq | Ne):
        left = values.get(p.path, UNKNOWN)
        right = values.get(p.value.path, UNKNOWN) if isinstance(p.value, Ref) else p.value
        if isinstance(left, Unknown) or isinstance(right, Unknown):
            return None
        same = left == right and type(left) is type(right)
        return same if isinstance(p, Eq) else not same
    if isinstance(p, In):
        value = values.get(p.path, UNKNOWN)
        if isinstance(value, Unknown):
            return None
        return any(value == v and type(value) is type(v) for v in p.values)
    if isinstance(p, Not):
        inner = partly(p.operand, values)
        return None if inner is None else not inner
    if isinstance(p, And | Or):
        settles = isinstance(p, Or)  # the item value that settles the junction
        result: bool | None = not settles
        for item in p.items:
            outcome = partly(item, values)
            if outcome is settles:
                return settles
            if outcome is None:
                result = None
        return result
    raise TypeError(f"no three-valued evaluation of {type(p).__name__}")


@dataclass(frozen=True)
class Happened:
    """One transition of the run (None: a change nothing explains) and the values it wrote."""

    transition: CompiledTransition | None
    writes: tuple[tuple[int, Value], ...]


class RunLog:
    """The transitions a run saw happen, in order, with what they wrote, since the window's start state."""

    def __init__(self, compiled: CompiledModel, start: State, limit: int = MAX_EVENTS) -> None:
        self.compiled = compiled
        self.limit = limit
        self.restart(start)

    def restart(self, start: State) -> None:
        """A new window from `start` (a station running orders: each order its own)."""
        self.start = tuple(start)
        self.state = list(start)
        self.events: list[Happened] = []
        self.overflowed = False

    def fired(self, transition: CompiledTransition) -> None:
        """One of the controller's own transitions (one outcome), applied to the log's state."""
        self._record(transition, transition.outcomes[0](tuple(self.state)))

    def effect(self, transition: CompiledTransition, after: State) -> None:
        """An effect that took the state to `after`."""
        self._record(transition, after)

    def unexplained(self, after: State, indices: Sequence[int]) -> None:
        self._record(None, tuple(after[i] if i in indices else v for i, v in enumerate(self.state)))

    def _record(self, transition: CompiledTransition | None, after: State) -> None:
        if self.overflowed:
            return
        if len(self.events) >= self.limit:
            self.overflowed = True
            self.events = []  # no bound from this window: nothing of it is needed
            return
        writes = tuple((i, v) for i, v in enumerate(after) if self.state[i] != v)
        if transition is None and not writes:
            return
        self.events.append(Happened(transition, writes))
        for i, v in writes:
            self.state[i] = v


@dataclass(frozen=True)
class ExclusionBound:
    seconds: float  # no schedule of the window's work the supervisor allows ends sooner
    resources: tuple[str, ...]  # whose intervals make it
    intervals: int


@dataclass
class _Interval:
    command: int  # event number of the command
    end: int  # of its last transition
    resource: str
    seconds: float  # the least it lasts
    head: float  # the earliest its command can fire
    tail: float  # the least time the window goes on after its end
    inside: tuple[dict[str, Value], ...]  # the resource's values inside it, in turn


class _Order:
    """What every schedule keeps of the run's order, with the earliest time of each transition and the least time
    after it."""

    def __init__(self, compiled: CompiledModel, log: RunLog, seconds: Mapping[str, float]) -> None:
        events = log.events
        n = len(events)
        self.before_state: list[State] = []
        self.readers: dict[tuple[int, int], list[int]] = {}  # (writer, variable) -> events reading it from there
        self.ancestors: list[int] = [0] * n  # bit sets
        self.writers: dict[int, list[int]] = {}  # variable -> the events writing it, in order
        self.duration = [seconds.get(e.transition.name, 0.0) if e.transition is not None
                         and e.transition.kind is TransitionKind.EFFECT else 0.0 for e in events]
        by_cause: list[list[int]] = [[] for _ in range(n)]
        by_read: list[list[int]] = [[] for _ in range(n)]  # later writers after a reader: no time between
        last: dict[int, int] = {}
        readers_of: dict[int, list[tuple[int, int]]] = {}  # variable -> (reader, writer it read from)
        state = list(log.start)
        for k, event in enumerate(events):
            self.before_state.append(tuple(state))
            t = event.transition
            reads = () if t is None else tuple(compiled.index[p] for p in t.source.read())
            cause = {v: last.get(v, -1) for v in reads}  # variable -> event it read it from (-1: the start)
            ancestors = 0
            for w in set(cause.values()):
                if w >= 0:
                    ancestors |= self.ancestors[w] | (1 << w)
                    by_cause[k].append(w)
            added: set[int] = set()
            grown = True
            while grown:  # a reader of what this event overwrites, from a writer before it, comes first
                grown = False
                for v, _value in event.writes:
                    for reader, writer in readers_of.get(v, ()):
                        if reader not in added and reader != k and (writer < 0 or ancestors >> writer & 1):
                            added.add(reader)
                            ancestors |= self.ancestors[reader] | (1 << reader)
                            by_read[k].append(reader)
                            grown = True
            self.ancestors[k] = ancestors
            for v in reads:
                readers_of.setdefault(v, []).append((k, cause[v]))
                self.readers.setdefault((cause[v], v), []).append(k)
            for v, value in event.writes:
                last[v] = k
                state[v] = value
                self.writers.setdefault(v, []).append(k)
        self.after_last = tuple(state)
        self.earliest = [0.0] * n
        for k in range(n):
            self.earliest[k] = max([self.earliest[w] + self.duration[k] for w in by_cause[k]]
                                   + [self.earliest[r] for r in by_read[k]] + [self.duration[k]])
        self.after = [0.0] * n
        successors: list[list[tuple[int, float]]] = [[] for _ in range(n)]
        for k in range(n):
            for w in by_cause[k]:
                successors[w].append((k, self.duration[k]))
            for r in by_read[k]:
                successors[r].append((k, 0.0))
        for k in range(n - 1, -1, -1):
            self.after[k] = max((self.after[s] + w for s, w in successors[k]), default=0.0)
        self.successors = successors

    def precedes(self, x: int, y: int) -> bool:
        return bool(self.ancestors[y] >> x & 1)

    def pinned(self, x: int, v: int, last_writer: int) -> bool:
        if last_writer >= 0 and not self.precedes(last_writer, x):
            return False
        return any(r == x or self.precedes(x, r) for r in self.readers.get((last_writer, v), ()))

    def longest(self, start: int, end: int) -> float:
        """The least time from `start` to `end` along the order's paths (durations of causes)."""
        reach = {start: 0.0}
        for k in range(start, end + 1):
            if k not in reach:
                continue
            for s, w in self.successors[k]:
                if s <= end and reach.get(s, -1.0) < reach[k] + w:
                    reach[s] = reach[k] + w
        return reach.get(end, 0.0)


def exclusion_bound(compiled: CompiledModel, log: RunLog, seconds: Mapping[str, float]) -> ExclusionBound | None:
    """The window's bound from the work the supervisor keeps apart (module docstring); None without a log."""
    if log.overflowed or not log.events:
        return None
    order = _Order(compiled, log, seconds)
    intervals = _intervals(compiled, log, order)
    if not intervals:
        return None
    return _kept_apart(compiled, log, order, intervals)


def _owner(transition: CompiledTransition | None) -> str | None:
    return writer_owner(transition.source) if transition is not None else None


def _is_command(event: Happened) -> bool:
    return event.transition is not None and event.transition.kind is TransitionKind.DELIBERATE


def _intervals(compiled: CompiledModel, log: RunLog, order: _Order) -> list[_Interval]:
    events = log.events
    owners = [_owner(e.transition) for e in events]
    own_variables: dict[str, list[int]] = {}
    for i, path in enumerate(compiled.paths):
        holder = compiled.model.resource_of(path)
        if holder is not None:
            own_variables.setdefault(holder.name, []).append(i)
    written_by_others: set[int] = set()  # a resource's variable written by another: not known inside its intervals
    for owner, event in zip(owners, events, strict=True):
        for v, _value in event.writes:
            holder = compiled.model.resource_of(compiled.paths[v])
            if holder is None or holder.name != owner:
                written_by_others.add(v)
    by_owner: dict[str, list[int]] = {}
    for k, owner in enumerate(owners):
        if owner is not None:
            by_owner.setdefault(owner, []).append(k)
    found: list[_Interval] = []
    for resource, mine in by_owner.items():
        variables = [v for v in own_variables.get(resource, ()) if v not in written_by_others]
        commands = [j for j, k in enumerate(mine) if _is_command(events[k])]
        for position, j in enumerate(commands):
            stop = commands[position + 1] if position + 1 < len(commands) else len(mine)
            chain = mine[j:stop]
            if not all(order.precedes(a, b) for a, b in itertools.pairwise(chain)):
                continue
            start, end = chain[0], chain[-1]
            if not all(order.precedes(x, start) or order.precedes(end, x) for x in mine if x not in chain):
                continue
            states = [order.before_state[k + 1] if k + 1 < len(events) else order.after_last for k in chain]
            inside = [{compiled.paths[v]: s[v] for v in variables} for s in states]
            for m in range(1, len(chain)):
                lasting = order.longest(start, chain[m])
                if lasting > 0:
                    found.append(_Interval(start, chain[m], resource, lasting, order.earliest[start],
                                           order.after[chain[m]], tuple(inside[:m])))
    return found


class _Apart:
    """Whether two intervals can overlap in some schedule, each pair asked once."""

    def __init__(self, compiled: CompiledModel, log: RunLog, order: _Order) -> None:
        self.compiled, self.log, self.order = compiled, log, order
        self.known: dict[tuple[int, int], bool] = {}
        self.pinned_at: dict[int, dict[str, Value]] = {}
        self.firing: dict[tuple[int, int], bool] = {}

    def __call__(self, a: _Interval, b: _Interval) -> bool:
        key = (id(a), id(b)) if id(a) < id(b) else (id(b), id(a))
        answer = self.known.get(key)
        if answer is None:
            answer = self._apart(a, b)
            self.known[key] = answer
        return answer

    def _apart(self, a: _Interval, b: _Interval) -> bool:
        order = self.order
        if order.precedes(a.end, b.command) or order.precedes(b.end, a.command):
            return True
        if a.command == b.command or a.resource == b.resource:
            return False
        return self._never_inside(a.command, b) and self._never_inside(b.command, a)

    def _never_inside(self, command: int, other: _Interval) -> bool:
        transition = self.log.events[command].transition
        assert transition is not None
        guard = self.compiled.guard_of(transition.source)
        known = self._pinned(command, guard)
        return all(partly(guard, {**known, **values}) is False for values in other.inside)

    def _pinned(self, command: int, guard: Predicate) -> dict[str, Value]:
        """The values of what the command's guard reads that are the same at the command in every schedule."""
        known = self.pinned_at.get(command)
        if known is None:
            order, compiled = self.order, self.compiled
            state = order.before_state[command]
            known = {}
            for path in guard.paths():
                v = compiled.index[path]
                if order.pinned(command, v, self._last_writer(command, v)):
                    known[path] = state[v]
            self.pinned_at[command] = known
        return known

    def _last_writer(self, k: int, v: int) -> int:
        writers = self.order.writers.get(v, [])
        return writers[bisect.bisect_left(writers, k) - 1] if bisect.bisect_left(writers, k) else -1


def _one_machine(chosen: Sequence[_Interval]) -> float:
    """No schedule ends sooner than, for the intervals starting no earlier than each one's head, that head plus
    their durations plus the least time left after any of them."""
    ordered = sorted(chosen, key=lambda i: i.head)
    best, total, least_tail = 0.0, 0.0, float("inf")
    for interval in reversed(ordered):
        total += interval.seconds
        least_tail = min(least_tail, interval.tail)
        best = max(best, interval.head + total + least_tail)
    return best


def _kept_apart(compiled: CompiledModel, log: RunLog, order: _Order, intervals: list[_Interval]) -> ExclusionBound:
    apart = _Apart(compiled, log, order)
    by_length = sorted(intervals, key=lambda i: -i.seconds)
    best: tuple[float, list[_Interval]] = (0.0, [])
    for resource in sorted({i.resource for i in intervals}):
        longest: dict[int, _Interval] = {}  # one interval per command: the longest
        for interval in intervals:
            if interval.resource == resource:
                kept = longest.get(interval.command)
                if kept is None or interval.seconds > kept.seconds:
                    longest[interval.command] = interval
        chosen = list(longest.values())
        for candidate in by_length:
            if candidate.resource != resource and all(apart(candidate, c) for c in chosen):
                chosen.append(candidate)
        bound = _one_machine(chosen)
        for _ in range(EXCHANGE_PASSES):  # an interval in for those it overlaps, when the bound grows by it
            changed = False
            for candidate in by_length:
                if any(candidate is c for c in chosen):
                    continue
                exchanged = [c for c in chosen if apart(candidate, c)] + [candidate]
                grown = _one_machine(exchanged)
                if grown > bound + 1e-9:
                    chosen, bound, changed = exchanged, grown, True
            if not changed:
                break
        if bound > best[0]:
            best = (bound, chosen)
    bound, chosen = best
    return ExclusionBound(bound, tuple(sorted({i.resource for i in chosen})), len(chosen))
