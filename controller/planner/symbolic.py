"""A symbolic planner member: breadth-first search over sets of states, as binary decision diagrams.

The original Sequence Planner asked a model checker (nuXmv, bounded model checking) for
the shortest counterexample to "the goal is never reached". This member does the same
with BDDs, under exactly the semantics of `steps.StepSystem` and `validate.check_plan`:

* a move is (transition number, outcome) of an ability transition of no disabled resource;
* where an (allowed) automatic guard holds, the only move is the first such automatic in
  model order; elsewhere the moves are the enabled effect outcomes and the enabled
  deliberate transitions that race no effect already due (`RaceCheck`);
* no state on the plan, the start included, is forbidden;
* the goal counts only in a stable state (no allowed automatic enabled, `stable_goal`).

Search: bidirectional breadth-first. Forward layers F_i are the states first reached after
i micro steps from the start; backward layers B_j the states whose shortest way to the
goal takes j steps. Each round extends the side with the smaller frontier (BDD nodes,
a backward node counted twice: a preimage costs about twice an image of the same size;
node counts are canonical for the fixed variable order, so the choice is reproducible).
The first new layer that meets the other side's reached set gives a shortest plan, of
i + j steps: every pair of layers met before was disjoint, so no plan is shorter. Forward
layers of exact distance couple every independent device (the sum of their distances is
fixed) and grow fast; meeting in the middle halves the depth of each side (2x on the
reference station's RobotHome). The backward layers depend on the goal alone, so they are
kept per goal and reused when the controller replans from another state. An exhausted side
proves the goal unreachable.

The plan is read from the meeting state (the least state of the meeting, in encoding
order) backwards through the forward layers and forwards through the backward layers,
taking the lowest (transition number, outcome) and the least state each time: the answer
depends on the model, the start, the goal and the calls made before (the kept layers) only.

Encoding: each variable is a bit vector (MSB first) of ceil(log2 |domain|) bits holding the
index of its value; invalid codes are excluded from every set. Images use a partitioned
transition relation: moves grouped by the set of variables they write (no frame condition
within a group), one relational product per group with the written bits quantified in the
same pass, primed bits renamed back. Preimages substitute the assignments into the layer
(a cofactor when they are constants).

Backend: `dd.cudd` (CUDD, C) when it imports, else the pure-Python `dd.autoref`
(correct, far slower). Dynamic reordering is off: on the reference station it spent ten
minutes sifting in the first search for 17% fewer nodes, and a fixed order keeps node
counts, budgets and chosen plans reproducible.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from common.model import Predicate, TransitionKind
from common.model.compiled import CompiledModel, CompiledTransition, State
from common.model.predicates import Ref
from common.model.variables import Value

from .search import SearchEnd
from .steps import Move
from .stopping import StopTest, check_stop
from .symbolic_encoding import Encoding, Function, and_exists, disjunction, variable_order

GOAL_CACHE = 16  # goals whose backward layers are kept
TIME_CHECK_EVERY = 8  # relational products between two looks at the clock inside a layer


@dataclass(frozen=True)
class SymbolicResult:
    moves: list[Move] | None  # None: no plan (see proven_unreachable / timed_out / reason)
    layers: int  # micro steps covered: forward + backward depth (the plan length when found)
    proven_unreachable: bool  # one side was exhausted without meeting the other: no plan exists
    timed_out: bool  # the layer/node budget or the deadline ran out first
    seconds: float
    reason: str = ""
    forward: int = 0  # forward layers computed
    backward: int = 0  # backward layers available (computed now or kept from earlier calls)
    nodes: int = 0  # BDD nodes of both reached sets at the end: the size of the symbolic work
    stopped: bool = False  # with timed_out: the stop test ended it (a newer request), not a budget


@dataclass(frozen=True)
class _SymbolicMove:
    number: int
    outcome: int
    fire: Function  # states where this exact move is the engine's (urgency and races included)
    relation: Function  # fire, and each written variable's primed bits hold its new value
    written: frozenset[int]
    substitution: dict[str, Function]  # written bit -> its value as a function of the state before
    constants: tuple[tuple[int, Value], ...]  # variable index, value assigned: a cheap filter for predecessors


@dataclass(frozen=True)
class _Cluster:
    """The moves writing one same set of variables, as one relation: one relational product per image."""

    bits: tuple[str, ...]  # the written bits, quantified
    relation: Function
    unprime: dict[str, str]  # primed bit -> its bit


@dataclass
class _Backward:
    """Backward layers for one goal: layers[j] holds the states whose shortest plan has j steps."""

    layers: list[Function]
    reached: Function
    complete: bool = False  # the last preimage added nothing: `reached` holds every state that can reach the goal


BACKWARD_WEIGHT = 2  # a backward layer costs about twice a forward one of equal size (measured)


@dataclass(frozen=True)
class SearchLimits:
    """The wall-clock deadline (`time.perf_counter()`) and the stop test of one search."""

    deadline: float | None = None
    stop: StopTest | None = None

    def ended(self) -> SearchEnd | None:
        """Why the search ends here (OUT_OF_BUDGET or STOPPED), or None. Once it has ended it stays ended, so
        a caller may ask again: a deadline stays past, and a newer request waits until it is read."""
        if self.deadline is not None and time.perf_counter() > self.deadline:
            return SearchEnd.OUT_OF_BUDGET
        if self.stop is not None and self.stop():
            return SearchEnd.STOPPED
        return None


NO_LIMITS = SearchLimits()


class SymbolicPlanner:
    """Shortest plans by symbolic bidirectional breadth-first search, for one compiled model, forbidden
    predicate and set of disabled resources. The owner keeps one per disabled set: building it costs
    about a second on the reference station, and it keeps the backward layers of recent goals.
    Calls are serialized by a lock (a BDD manager is not thread-safe)."""

    def __init__(
        self, compiled: CompiledModel, forbidden: Predicate | None, disabled: frozenset[str] = frozenset(),
        stop: StopTest | None = None, timed_races: Mapping[int, tuple[CompiledTransition, ...]] | None = None,
    ) -> None:
        """`stop` ends the build (`stopping.Stopped`): the owner stores the member only once it is built.
        `timed_races`: the races plans lost in time (steps.TimedRaces.known), each victim not taken while one
        of its effects is due, as every other member does."""
        began = time.perf_counter()
        self.compiled = compiled
        self.forbidden = forbidden
        self.disabled = frozenset(disabled)
        self._lock = threading.Lock()

        def allowed(t: CompiledTransition) -> bool:
            return not (t.resources & self.disabled)

        automatic = [t for t in compiled.automatic if allowed(t)]
        controlled = [t for t in (*compiled.deliberate, *compiled.effects) if allowed(t)]
        written = {i for t in (*automatic, *controlled) for i in t.writes}
        enc = self.encoding = Encoding(compiled, written, variable_order(compiled, written))
        forbidden_set = enc.predicate(forbidden) if forbidden is not None else enc.false
        self.allowed: Function = enc.valid & ~forbidden_set  # the states a plan may pass through

        guards = {t.number: enc.guard(t) for t in (*automatic, *controlled)}
        moves: list[_SymbolicMove] = []
        earlier = enc.false  # some earlier automatic is enabled: this one must wait
        for t in automatic:
            check_stop(stop)
            moves.append(self._move(t, 0, guards[t.number] & ~earlier))
            earlier |= guards[t.number]
        self.urgent: Function = earlier
        stable = ~earlier
        races = self._races(controlled, guards, stop)
        for t in controlled:
            check_stop(stop)
            fire = stable & guards[t.number]
            race = races.get(t.number) if t.kind is TransitionKind.DELIBERATE else None
            if race is not None:
                fire &= ~race
            for due in (timed_races or {}).get(t.number, ()):
                if allowed(due):
                    due_guard: Function = guards.setdefault(due.number, enc.guard(due))
                    fire &= ~due_guard
            if fire == enc.false:
                continue  # never the engine's move (a synthesized guard can be false)
            moves.extend(self._move(t, o, fire) for o in range(len(t.outcomes)))
        # Plans are read trying the moves in this order: the lowest (transition number, outcome) first.
        self.moves: tuple[_SymbolicMove, ...] = tuple(sorted(moves, key=lambda m: (m.number, m.outcome)))
        self.clusters = self._clusters()
        self.writes = self._writes()
        self._backward: OrderedDict[Predicate, _Backward] = OrderedDict()
        self.build_seconds = time.perf_counter() - began

    # --- construction -------------------------------------------------------------------------
    def _move(self, t: CompiledTransition, outcome: int, fire: Function) -> _SymbolicMove:
        enc, compiled = self.encoding, self.compiled
        relation = fire
        constants = []
        for a in t.source.outcomes[outcome]:
            i = compiled.index[a.path]
            if isinstance(a.value, Ref):
                relation &= enc.equal(i, compiled.index[a.value.path], primed_i=True)
            else:
                relation &= enc.value(i, a.value, primed=True)
                constants.append((i, a.value))
        written = frozenset(compiled.index[a.path] for a in t.source.outcomes[outcome])
        return _SymbolicMove(t.number, outcome, fire, relation, written, enc.substitution(t, outcome),
                             tuple(constants))

    def _clusters(self) -> tuple[_Cluster, ...]:
        """Moves grouped by the variables they write: within a group no frame condition is needed, and one
        relational product replaces an image and a union per move (the unions dominated the time)."""
        enc = self.encoding
        groups: dict[frozenset[int], list[_SymbolicMove]] = {}
        for m in self.moves:
            groups.setdefault(m.written, []).append(m)
        clusters = []
        for written, members in sorted(groups.items(), key=lambda item: sorted(item[0])):
            order = sorted(written)
            bits = tuple(name for i in order for name in enc.bits[i])
            primes = tuple(name for i in order for name in enc.primes[i])
            clusters.append(_Cluster(bits, disjunction((m.relation for m in members), enc.false),
                                     dict(zip(primes, bits, strict=True))))
        return tuple(clusters)

    def _races(self, controlled: list[CompiledTransition], guards: dict[int, Function],
               stop: StopTest | None) -> dict[int, Function]:
        """For each deliberate t, the states where `RaceCheck.races(state, t)` holds, symbolically.

        The pairs (f, rivals) are chosen exactly as RaceCheck chooses them; the condition on the
        state after t's first outcome is then pulled back through that outcome by composition."""
        enc = self.encoding
        effects = [t for t in self.compiled.effects if not (t.resources & self.disabled)]
        for f in effects:
            guards.setdefault(f.number, enc.guard(f))
        after_cache: dict[tuple[int, int, int], Function] = {}

        def guard_after(g: CompiledTransition, t: CompiledTransition, outcome: int) -> Function:
            """g's guard holds after t's outcome fires."""
            key = (g.number, t.number, outcome)
            found = after_cache.get(key)
            if found is None:
                found = after_cache[key] = enc.compose(guards[g.number], enc.substitution(t, outcome))
            return found

        # The state after t is due f and e, and either firing first disables the other.
        overtaken: dict[int, Function] = {}
        for f in effects:
            check_stop(stop)
            condition = enc.false
            for e in effects:
                if e is f or not (e.writes & f.reads or f.writes & e.reads):
                    continue
                undone = disjunction((~guard_after(f, e, o) for o in range(len(e.outcomes))), enc.false)
                undone |= disjunction((~guard_after(e, f, o) for o in range(len(f.outcomes))), enc.false)
                condition |= guards[e.number] & undone
            overtaken[f.number] = guards[f.number] & condition
        result: dict[int, Function] = {}
        for t in controlled:
            check_stop(stop)
            if t.kind is not TransitionKind.DELIBERATE:
                continue
            after = disjunction((overtaken[f.number] for f in effects if f.reads & t.writes), enc.false)
            if after != enc.false:
                result[t.number] = enc.compose(after, enc.substitution(t, 0))
        return result

    # --- images -----------------------------------------------------------------------------------
    def _image(self, frontier: Function, limits: SearchLimits = NO_LIMITS) -> Function | None:
        """The states one move after `frontier` (None: the deadline passed or the stop test said so)."""
        bdd, false = self.encoding.bdd, self.encoding.false
        parts = []
        for count, cluster in enumerate(self.clusters):
            if count % TIME_CHECK_EVERY == 0 and limits.ended() is not None:
                return None
            after = and_exists(bdd, frontier, cluster.relation, cluster.bits)
            if after != false:
                parts.append(bdd.let(cluster.unprime, after))
        return disjunction(parts, false)

    def _preimage(self, target: Function, limits: SearchLimits = NO_LIMITS) -> Function | None:
        """The states with a move into `target` (None: the deadline passed or the stop test said so).

        By substitution (wp), not by the relations: renaming a layer into primed bits once per
        cluster cost more than the products themselves; a constant assignment is a cofactor."""
        bdd, false = self.encoding.bdd, self.encoding.false
        parts = []
        for count, (substitution, fire) in enumerate(self.writes):
            if count % TIME_CHECK_EVERY == 0 and limits.ended() is not None:
                return None
            before = fire & bdd.let(substitution, target)
            if before != false:
                parts.append(before)
        return disjunction(parts, false)

    def _writes(self) -> tuple[tuple[dict[str, Any], Function], ...]:
        """Moves grouped by what they write (same bits, same values): one substitution, the union of their fires."""
        enc = self.encoding
        groups: dict[tuple[object, ...], tuple[dict[str, Any], list[Function]]] = {}
        for m in self.moves:
            substitution: dict[str, Any] = m.substitution
            if all(u == enc.true or u == enc.false for u in substitution.values()):
                substitution = {name: u == enc.true for name, u in substitution.items()}  # a cofactor: cheaper
                key: tuple[object, ...] = tuple(sorted(substitution.items()))
            else:
                key = (m.number, m.outcome)
            groups.setdefault(key, (substitution, []))[1].append(m.fire)
        return tuple((substitution, disjunction(fires, enc.false)) for substitution, fires in groups.values())

    def _goal_layers(self, goal: Predicate) -> _Backward:
        found = self._backward.get(goal)
        if found is not None:
            self._backward.move_to_end(goal)
            return found
        enc = self.encoding
        # The goal counts only where no automatic is due: the engine fires it before it looks at any goal.
        base = enc.predicate(goal) & ~self.urgent & self.allowed
        found = self._backward[goal] = _Backward([base], base)
        if len(self._backward) > GOAL_CACHE:
            self._backward.popitem(last=False)
        return found

    def clear_cache(self) -> None:
        with self._lock:
            self._backward.clear()

    # --- search -----------------------------------------------------------------------------------
    def search(
        self,
        start: State,
        goal: Predicate,
        *,
        max_layers: int = 10_000,
        max_nodes: int | None = None,
        deadline: float | None = None,
        stop: StopTest | None = None,
    ) -> SymbolicResult:
        """A shortest plan from `start` to a stable state satisfying `goal`, as moves (transition number, outcome).

        Budgets: the forward and backward depths together at most `max_layers`, no frontier of more
        than `max_nodes` BDD nodes expanded (both deterministic), and the wall-clock `deadline` (a
        `time.perf_counter()` value) and `stop` (a newer request), both also looked at inside a layer: a
        layer is kept only whole, so the goal's kept layers stay exact whenever the search ends."""
        with self._lock:
            return self._search(start, goal, max_layers, max_nodes, SearchLimits(deadline, stop))

    def _search(
        self, start: State, goal: Predicate, max_layers: int, max_nodes: int | None, limits: SearchLimits
    ) -> SymbolicResult:
        began = time.perf_counter()
        enc = self.encoding
        false = enc.false
        if len(start) != len(self.compiled.paths):
            raise ValueError(f"a state has {len(self.compiled.paths)} values, got {len(start)}")
        origin = enc.state(start)
        forward = [origin]
        reached = origin
        back = self._goal_layers(goal)

        def result(moves: list[Move] | None, reason: str = "", proven: bool = False,
                   timed_out: bool = False, stopped: bool = False) -> SymbolicResult:
            depth = len(moves) if moves is not None else len(forward) - 1 + len(back.layers) - 1
            return SymbolicResult(moves, depth, proven, timed_out, time.perf_counter() - began, reason,
                                  len(forward) - 1, len(back.layers) - 1, reached.dag_size + back.reached.dag_size,
                                  stopped)

        def ended_early(end: SearchEnd | None) -> SymbolicResult:
            depth = len(forward) - 1 + len(back.layers) - 1
            if end is SearchEnd.STOPPED:
                return result(None, f"stopped by a newer request ({depth} layers)", timed_out=True, stopped=True)
            return result(None, f"no plan within the time limit ({depth} layers)", timed_out=True)

        if origin & self.allowed == false:
            return result(None, "the start state is forbidden")
        if origin & back.reached != false:
            j = next(j for j, layer in enumerate(back.layers) if origin & layer != false)
            kept = "" if j == 0 else "the goal's kept layers hold the start"
            return result(self._follow(start, back.layers, j), kept)
        while True:
            depth = len(forward) - 1 + len(back.layers) - 1
            if back.complete:
                return result(None, f"unreachable: every state that can reach the goal explored "
                                    f"({len(back.layers) - 1} layers)", proven=True)
            if depth >= max_layers:
                return result(None, f"no plan within {max_layers} layers", timed_out=True)
            ended = limits.ended()
            if ended is not None:
                return ended_early(ended)
            ahead, behind = forward[-1].dag_size, back.layers[-1].dag_size
            go_forward = ahead <= BACKWARD_WEIGHT * behind
            if max_nodes is not None and (ahead if go_forward else behind) > max_nodes:
                return result(None, f"no plan within {max_nodes} BDD nodes per layer", timed_out=True)
            if go_forward:
                image = self._image(forward[-1], limits)
                if image is None:
                    return ended_early(limits.ended())
                new = image & self.allowed & ~reached
                if new == false:
                    return result(None, f"unreachable: every reachable state explored ({len(forward) - 1} "
                                        f"layers)", proven=True)
                forward.append(new)
                reached |= new
                meet = new & back.reached
                if meet != false:
                    j = next(j for j, layer in enumerate(back.layers) if meet & layer != false)
                    return result(self._join(forward, len(forward) - 1, back.layers, j))
            else:
                before = self._preimage(back.layers[-1], limits)
                if before is None:
                    return ended_early(limits.ended())
                new = before & self.allowed & ~back.reached
                if new == false:
                    back.complete = True
                    continue
                back.layers.append(new)
                back.reached |= new
                meet = new & reached
                if meet != false:
                    i = next(i for i, layer in enumerate(forward) if meet & layer != false)
                    return result(self._join(forward, i, back.layers, len(back.layers) - 1))

    # --- reading the plan ---------------------------------------------------------------------------
    def _join(self, forward: list[Function], i: int, backward: list[Function], j: int) -> list[Move]:
        meeting = self.encoding.least(forward[i] & backward[j])
        return self._trace_back(forward, i, meeting) + self._follow(meeting, backward, j)

    def _trace_back(self, forward: list[Function], i: int, state: State) -> list[Move]:
        """Moves from the start to `state` (in forward[i]): from each state, the lowest move and least predecessor."""
        enc = self.encoding
        false = enc.false
        moves: list[Move] = []
        for depth in range(i - 1, -1, -1):
            here = enc.state(state)
            for m in self.moves:
                if any(state[k] != value for k, value in m.constants):
                    continue  # the move would have left a different value
                before = enc.compose(here, m.substitution) & m.fire  # small: the layer last
                if before != false and (before := before & forward[depth]) != false:
                    state = enc.least(before)
                    moves.append((m.number, m.outcome))
                    break
            else:  # pragma: no cover - every state of a layer has a predecessor in the layer before
                raise AssertionError(f"no predecessor in forward layer {depth}")
        moves.reverse()
        return moves

    def _follow(self, state: State, backward: list[Function], j: int) -> list[Move]:
        """Moves from `state` (in backward[j]) to the goal: the lowest move into the next layer each time."""
        enc = self.encoding
        false = enc.false
        transitions = self.compiled.transitions
        moves: list[Move] = []
        for depth in range(j - 1, -1, -1):
            here = enc.state(state)
            for m in self.moves:
                if here & m.fire == false:
                    continue
                after = transitions[m.number].outcomes[m.outcome](state)
                if enc.state(after) & backward[depth] != false:
                    state = after
                    moves.append((m.number, m.outcome))
                    break
            else:  # pragma: no cover - every state of a backward layer has a move into the layer below
                raise AssertionError(f"no move into backward layer {depth}")
        return moves
