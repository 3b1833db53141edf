"""The portfolio's member that improves a plan by *time*: the same steps in another order that the engine finishes
sooner, by the station's durations (pure).

The other members look for fewer steps; a shortest plan is not the fastest one. Run as a partial order
(controller/deorder.py) or a trace, a plan's steps still wait for some steps before them (those their guards need,
those whose writes they would disturb), and which of those come first is the sequence's choice: the robot's job
the operator needs done last holds the operator back behind the others. This member climbs from the plan along
its critical path (the dependencies that decide when it ends): a step moved across a dependency that is not a
causal link (just before the other step, or further back as far as the last step its guard needs), the earlier
step moved past the later, or a device's round trip (its commands from some values back to the same) swapped with
the one before it. A move is kept when the engine still takes the new sequence to the goals (`revalidate`: the
planner's own check with the engine's semantics, urgency of automatic transitions and the races the planner knows
included) and it ends sooner, or as soon with its steps done earlier in all (which lets the climb cross a plateau
of several critical paths); the climb goes on from the first such move. It stops at a sequence no move improves,
or at its budget: `tries` sequences checked (a count: virtual time stays reproducible), or a stop test (a
deadline, a newer request).

Predicted as `controller/cycle.py` predicts a run (each effect its longest, commands instant, every step as
soon as the steps it depends on have happened). The caller checks the result in time (controller/timed_check.py)
before it runs, as every plan is.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace

from common.model import Duration, TransitionKind
from common.model.compiled import CompiledModel, State
from common.model.durations import duration_in, effect_owner, writer_owner

from .control import PlanRequest
from .cycle import step_finishes, step_seconds
from .deorder import Execution, Ordering, order
from .planner import Plan, Planner
from .planner.plans import PlanStep
from .planner.portfolio import RETIME_TRIES
from .timed_check import Revalidate

EPSILON_S = 1e-6
RETIMES_KEPT = 256  # plans remembered with what the member found for them


@dataclass(frozen=True)
class Retimed:
    """A faster order of a plan's steps."""

    plan: Plan
    before_s: float  # the plan's predicted finish
    after_s: float  # this one's
    tried: int  # sequences checked


@dataclass(frozen=True)
class _Timed:
    plan: Plan
    ordering: Ordering
    durations: list[float]
    finishes: list[float]

    @property
    def score(self) -> tuple[float, float]:
        return max(self.finishes, default=0.0), sum(self.finishes)


def longest_seconds(compiled: CompiledModel, durations: Mapping[str, Duration]) -> dict[str, float]:
    """Each effect's longest duration by name, from a `DurationTable.keyed()` mapping (the planner's process)."""
    return {t.name: duration_in(durations, t.name, effect_owner(t.source)).max_s
            for t in compiled.effects if t.writes}


def retime(compiled: CompiledModel, plan: Plan, seconds: Mapping[str, float], execution: Execution,
           revalidate: Revalidate, *, tries: int = RETIME_TRIES,
           stop: Callable[[], bool] | None = None) -> Retimed | None:
    """A faster order of `plan`'s steps from its start state, or None when no move finds one (or the engine
    runs every plan in sequence, where the order changes nothing)."""
    if execution is Execution.SEQUENCE or tries <= 0 or not any(
            step.kind is TransitionKind.EFFECT for step in plan.steps):
        return None
    best = _timed(compiled, plan, seconds, execution)
    first = best.score[0]
    seen = {plan.steps}
    tried = 0
    climbing = True
    while climbing:
        climbing = False
        for steps in _moves(compiled, best):
            if steps in seen:
                continue
            if tried >= tries or (stop is not None and stop()):
                break
            seen.add(steps)
            tried += 1
            candidate = _checked(best.plan, steps, revalidate)
            if candidate is None:
                continue
            timed = _timed(compiled, candidate, seconds, execution)
            if timed.score < best.score and timed.score[0] <= best.score[0] + EPSILON_S:
                best, climbing = timed, True  # the first move that improves: the critical path has changed
                break
    if best.score[0] >= first - EPSILON_S:
        return None
    stats = replace(plan.stats, method=f"{plan.stats.method}, retimed")
    return Retimed(replace(best.plan, goals=plan.goals, stats=stats, execution=plan.execution), first,
                   best.score[0], tried)


class Retimer:
    """The member for one planner, durations and engine order (the controller's loop, the planner process): what it
    found for a plan from a start is remembered (the same plans come back order after order, reused by the
    planner), unless a deadline or a stop cut the search short."""

    def __init__(self, planner: Planner, seconds: Mapping[str, float], execution: Execution,
                 kept: int = RETIMES_KEPT) -> None:
        self.planner = planner
        self.seconds = seconds
        self.execution = execution
        self.kept = kept
        self._found: OrderedDict[tuple[object, ...], Retimed | None] = OrderedDict()

    def faster(self, plan: Plan, request: PlanRequest, tries: int = RETIME_TRIES, deadline: float | None = None,
               stop: Callable[[], bool] | None = None) -> Retimed | None:
        """`retime` for the plan answering `request`: each order checked for the goals the plan was found for (the
        request's, and the finished products it must leave holding)."""
        goals = {**request.keep, **request.goals}
        key = (plan.steps, plan.states[0], frozenset(goals), request.disabled, tries,
               self.planner.timed_races.version)
        if key in self._found:
            self._found.move_to_end(key)
            return self._found[key]
        cut = False

        def stopping() -> bool:
            nonlocal cut
            cut = cut or (deadline is not None and time.perf_counter() > deadline) or (stop is not None and stop())
            return cut

        def revalidate(start: State, steps: Sequence[PlanStep]) -> Plan | None:
            return self.planner.revalidate(start, steps, goals, request.disabled)

        found = retime(self.planner.compiled, plan, self.seconds, self.execution, revalidate, tries=tries,
                       stop=stopping)
        if not cut:
            self._found[key] = found
            while len(self._found) > self.kept:
                self._found.popitem(last=False)
        return found


def _checked(plan: Plan, steps: tuple[PlanStep, ...], revalidate: Revalidate) -> Plan | None:
    """`steps` as a plan if the engine takes them to the goals: checked from the first step where they differ from
    `plan`'s (up to there the states and the checks are the plan's own)."""
    same = next((k for k, (a, b) in enumerate(zip(plan.steps, steps, strict=True)) if a != b), len(steps))
    rest = revalidate(plan.states[same], steps[same:])
    if rest is None:
        return None
    return replace(rest, steps=plan.steps[:same] + rest.steps, states=plan.states[:same] + rest.states)


def _timed(compiled: CompiledModel, plan: Plan, seconds: Mapping[str, float], execution: Execution) -> _Timed:
    ordering = order(compiled, plan, execution)
    durations = step_seconds(compiled, plan, seconds)
    return _Timed(plan, ordering, durations, step_finishes(ordering, durations))


def _moves(compiled: CompiledModel, timed: _Timed) -> Iterator[tuple[PlanStep, ...]]:
    """Each sequence one move away from the plan's, latest critical dependency first: across one that is not a
    causal link, the later step just before the earlier one, or the earlier just past the later; across any, a
    device's round trip swapped with the one before it; then, across one that is not a causal link, the later
    step further back, as far as the last step its guard needs (an automatic step in between may leave no room
    just before the earlier one: the engine fires it at once)."""
    steps = timed.plan.steps
    edges = _critical_edges(timed)
    loose = [(before, after) for before, after in edges if before not in timed.ordering.producers[after]]
    for before, after in loose:
        yield _moved(steps, after, before)  # the later step first
        yield _moved(steps, before, after)  # the earlier step past the later one
    trips = _RoundTrips(compiled, timed.plan)
    for _before, after in edges:
        yield from trips.swapped(after)
    for before, after in loose:
        needed = max(timed.ordering.producers[after], default=-1)
        for position in range(before - 1, needed, -1):
            yield _moved(steps, after, position)


def _moved(steps: tuple[PlanStep, ...], source: int, target: int) -> tuple[PlanStep, ...]:
    """Step `source` moved to where step `target` is, `target` and those between them moved up one place."""
    moved = list(steps)
    moved.insert(target, moved.pop(source))
    return tuple(moved)


class _RoundTrips:
    """A device's round trips in a plan: the steps from one point where its commands have some values to the next
    where they have the same again (a robot sent from home to a bolt and back, a tool switched on and off). Two
    round trips in a row may be done the other way round, as far as the device goes: the one a step belongs
    to is swapped with the one before it, the steps of other devices between them moved along or left where
    they are. A command that was already stepping through its values is put back as it was by `revalidate`
    whenever the swap takes something another device needed."""

    def __init__(self, compiled: CompiledModel, plan: Plan) -> None:
        self.plan = plan
        model = compiled.model
        self.owner = [writer_owner(compiled.by_name[step.transition].source) for step in plan.steps]
        self.commands = {r.name: [compiled.index[v.path] for v in r.commands] for r in model.resources}

    def swapped(self, j: int) -> Iterator[tuple[PlanStep, ...]]:
        owner = self.owner[j]
        commands = self.commands.get(owner) if owner is not None else None
        if not commands:
            return
        states = self.plan.states
        at = [tuple(state[i] for i in commands) for state in states]
        # the points before and after j where the device's commands are as they were at j's round trip's start
        for q in range(j, -1, -1):
            later = next((s for s in range(j + 1, len(states)) if at[s] == at[q]), None)
            if later is None:
                continue
            earlier = next((p for p in range(q - 1, -1, -1) if at[p] == at[q]), None)
            if earlier is None:
                return
            yield from self._swap(earlier, q, later, owner)
            return

    def _swap(self, p: int, q: int, s: int, owner: str | None) -> Iterator[tuple[PlanStep, ...]]:
        """Steps p..q-1 and q..s-1 the other way round: all of them, then only the device's own."""
        steps = self.plan.steps
        yield steps[:p] + steps[q:s] + steps[p:q] + steps[s:]
        own = [k for k in range(q, s) if self.owner[k] == owner]
        others = [k for k in range(q, s) if self.owner[k] != owner]
        if others:
            yield (steps[:p] + tuple(steps[k] for k in own) + steps[p:q] + tuple(steps[k] for k in others)
                   + steps[s:])


def _critical_edges(timed: _Timed) -> list[tuple[int, int]]:
    """The dependencies (earlier, later) along which the plan's end is decided: from each step that ends last,
    back through every dependency that finishes just when the step starts."""
    finishes, durations, depends = timed.finishes, timed.durations, timed.ordering.depends
    if not finishes:
        return []
    end = max(finishes)
    frontier = [j for j, f in enumerate(finishes) if f >= end - EPSILON_S]
    visited, edges = set(frontier), []
    while frontier:
        j = frontier.pop()
        begins = finishes[j] - durations[j]
        for d in sorted(depends[j], reverse=True):
            if finishes[d] >= begins - EPSILON_S:
                edges.append((d, j))
                if d not in visited:
                    visited.add(d)
                    frontier.append(d)
    edges.sort(key=lambda edge: -edge[1])
    return edges
