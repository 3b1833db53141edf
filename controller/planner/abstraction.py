"""Projections of a model onto a few variables (pattern databases) and backward distances in them.

An abstract state is the projection of a concrete state onto the chosen variables,
coded as a mixed-radix integer over domain indices. Abstract transitions
over-approximate the concrete ones: a guard is put in negation normal form and every
literal over a dropped variable becomes true; assignments to dropped variables are
dropped; `x := y` with `y` dropped lets `x` take any value; urgency is ignored. So
every concrete path maps onto an abstract path, and since a step that leaves the
projection unchanged is an abstract self-loop, an abstract distance is a lower bound
on the number of concrete steps that change the projected variables.

States that are forbidden whatever the dropped variables hold (the forbidden
predicate under-approximated: dropped literals false) are left out: no plan visits them.
Urgency is kept where the projection decides it: in an abstract state where an
automatic transition is certainly enabled (its guard under-approximated holds), every
concrete step is an automatic one no later in model order, so nothing else leaves it.
"""

from __future__ import annotations

import itertools
import operator
from collections.abc import Callable, Iterable, Sequence

from common.model import FALSE, TRUE, And, Const, Eq, In, IsTrue, Ne, Not, Or, Predicate, Ref
from common.model.compiled import CompiledTransition, State, predicate_source

from .steps import StepSystem
from .stopping import StopTest, check_stop

INF = 1 << 40
CHECK_EVERY_STATES = 4096  # abstract states handled between two stop checks in a loop over all of them


# --- predicates, approximated ------------------------------------------------------------
def _fold(items: list[Predicate], conjunction: bool) -> Predicate:
    kept: list[Predicate] = []
    for item in items:
        if isinstance(item, Const):
            if item.value != conjunction:
                return item  # false in a conjunction, true in a disjunction
            continue
        kept.append(item)
    if not kept:
        return TRUE if conjunction else FALSE
    if len(kept) == 1:
        return kept[0]
    return And(tuple(kept)) if conjunction else Or(tuple(kept))


def _negate_literal(p: Predicate) -> Predicate:
    if isinstance(p, Eq):
        return Ne(p.path, p.value)
    if isinstance(p, Ne):
        return Eq(p.path, p.value)
    return Not(p)


def approximate(p: Predicate, keep: set[str], over: bool = True, positive: bool = True) -> Predicate:
    """`p` in negation normal form with every literal that mentions a variable outside `keep` replaced by
    true (`over`: an over-approximation) or false (an under-approximation)."""
    if isinstance(p, Const):
        return Const(p.value == positive)
    if isinstance(p, Not):
        return approximate(p.operand, keep, over, not positive)
    if isinstance(p, And | Or):
        conjunction = isinstance(p, And) == positive
        return _fold([approximate(i, keep, over, positive) for i in p.items], conjunction)
    if isinstance(p, IsTrue | Eq | Ne | In):
        if not p.paths() <= keep:
            return Const(over)
        return p if positive else _negate_literal(p)
    raise TypeError(f"unknown predicate node {p!r}")


def rename(p: Predicate, old: str, new: str) -> Predicate:
    """`p` with variable `old` read as `new` (the atom of `x := y`, seen before the assignment)."""
    if isinstance(p, Const):
        return p
    if isinstance(p, IsTrue):
        return IsTrue(new) if p.path == old else p
    if isinstance(p, Eq | Ne):
        path = new if p.path == old else p.path
        value = Ref(new) if isinstance(p.value, Ref) and p.value.path == old else p.value
        return type(p)(path, value)
    if isinstance(p, In):
        return In(new, p.values) if p.path == old else p
    if isinstance(p, Not):
        return Not(rename(p.operand, old, new))
    if isinstance(p, And | Or):
        return type(p)(tuple(rename(i, old, new) for i in p.items))
    raise TypeError(f"unknown predicate node {p!r}")


# --- the abstraction ----------------------------------------------------------------------
class Abstraction:
    """The step system projected onto `variables` (indices into the state tuple)."""

    def __init__(
        self,
        system: StepSystem,
        variables: Iterable[int],
        forbidden: Predicate | None = None,
        costed: frozenset[int] | None = None,
    ) -> None:
        """`costed`: the transitions (numbers) that cost 1 here, the others 0 (cost partitioning); None: all."""
        compiled = system.compiled
        self.system = system
        self.costed = costed
        self.variables: tuple[int, ...] = tuple(sorted(set(variables)))
        self.paths = tuple(compiled.paths[i] for i in self.variables)
        self.keep = set(self.paths)
        self.position = {path: k for k, path in enumerate(self.paths)}
        self.values: tuple[tuple[object, ...], ...] = tuple(compiled.domains[i].values for i in self.variables)
        self.sizes = tuple(len(v) for v in self.values)
        strides = []
        stride = 1
        for size in reversed(self.sizes):
            strides.append(stride)
            stride *= size
        self.strides = tuple(reversed(strides))
        self.size = stride
        self.index = self._index_function()
        self._free: dict[tuple[int, ...], list[int]] = {}
        self._distances: dict[object, list[int]] = {}
        self.blocked = bytearray(self.size)
        if forbidden is not None:
            certain = approximate(forbidden, self.keep, over=False)
            for state in self.states_where(certain):
                self.blocked[state] = 1
        # Transitions that can change the projection: the only ones an abstract distance counts.
        self.relevant: tuple[CompiledTransition, ...] = tuple(
            t for t in system.transitions if any(compiled.paths[i] in self.keep for i in t.writes)
        )
        self._urgent_after: list[int] | None = None
        self._automatic_position = {t.number: p for p, t in enumerate(system.automatic)}
        self._predecessors: tuple[list[list[int]], list[list[int]]] | None = None
        self._successors: list[list[int]] | None = None
        self._restricted: tuple[list[list[int]], list[list[int]]] = ([], [])
        self._restricted_version = -1
        self._initial_index: int | None = None
        self._condensation: tuple[list[int], list[list[int]], list[list[int]]] = ([], [], [])
        self._condensed_version = -1
        self.reachable = bytearray(self.size)  # forward from the starts seen so far (see `reach_from`)
        self.reachable_version = 0

    def describe(self) -> str:
        return ", ".join(self.paths) or "(nothing)"

    def _index_function(self) -> Callable[[State], int]:
        if not self.variables:
            return lambda s: 0
        tables = [
            {value: k * stride for k, value in enumerate(values)}
            for values, stride in zip(self.values, self.strides, strict=True)
        ]
        terms = " + ".join(f"t{k}[s[{i}]]" for k, i in enumerate(self.variables))
        namespace: dict[str, object] = {f"t{k}": table for k, table in enumerate(tables)}
        exec(f"def index(s):\n    return {terms}", namespace)
        return namespace["index"]  # type: ignore[return-value]  # compiled by exec: the namespace holds objects

    # --- enumeration ----------------------------------------------------------------------
    def free_offsets(self, positions: Sequence[int]) -> list[int]:
        """Offsets of every combination of the projected variables *not* in `positions`."""
        key = tuple(sorted(positions))
        offsets = self._free.get(key)
        if offsets is None:
            others = [k for k in range(len(self.variables)) if k not in key]
            offsets = [0]
            for k in others:
                stride = self.strides[k]
                offsets = [o + v * stride for o in offsets for v in range(self.sizes[k])]
            self._free[key] = offsets
        return offsets

    def _local(self, positions: Sequence[int]) -> Iterable[tuple[tuple[object, ...], tuple[int, ...], int]]:
        """Every assignment to `positions`: (values, value indices, offset)."""
        strides = [self.strides[k] for k in positions]
        values = itertools.product(*(self.values[k] for k in positions))
        for combo, vals in zip(itertools.product(*(range(self.sizes[k]) for k in positions)), values, strict=True):
            yield vals, combo, sum(map(operator.mul, combo, strides))

    def _test(self, predicate: Predicate, positions: Sequence[int]) -> Callable[[tuple[object, ...]], bool]:
        """`predicate` compiled over the value tuples `_local(positions)` yields."""
        local = {self.paths[k]: n for n, k in enumerate(positions)}
        return eval(f"lambda s: {predicate_source(predicate, local)}")  # source generated from the model

    def _positions(self, predicate: Predicate) -> list[int]:
        return sorted(self.position[p] for p in predicate.paths() if p in self.position)

    def states_where(self, predicate: Predicate) -> list[int]:
        """Abstract states where the over-approximation of `predicate` holds."""
        approx = approximate(predicate, self.keep)
        if approx == FALSE:
            return []
        positions = self._positions(approx)
        free = self.free_offsets(positions)
        test = self._test(approx, positions)
        result: list[int] = []
        for vals, _, offset in self._local(positions):
            if test(vals):
                result.extend(offset + f for f in free)
        return result

    def _effects(
        self, t: CompiledTransition, outcome: int, condition: Predicate = TRUE, stop: StopTest | None = None
    ) -> Iterable[tuple[list[int], int, list[int]]]:
        """(positions, pre offset, post offsets) for every local assignment where the guard can hold."""
        guard = approximate(And((self.system.compiled.guard_of(t.source), condition)), self.keep)
        if guard == FALSE:
            return
        # (position, value index | ("copy", position) | None = any)
        writes: list[tuple[int, int | tuple[str, int] | None]] = []
        for action in t.source.outcomes[outcome]:
            k = self.position.get(action.path)
            if k is None:
                continue
            if isinstance(action.value, Ref):
                source = self.position.get(action.value.path)
                writes.append((k, None if source is None else ("copy", source)))
            else:
                writes.append((k, self.values[k].index(action.value)))
        positions = sorted(
            set(self._positions(guard))
            | {k for k, _ in writes}
            | {w[1] for _, w in writes if isinstance(w, tuple)}
        )
        place = {k: n for n, k in enumerate(positions)}
        test = self._test(guard, positions)
        for looked, (vals, combo, offset) in enumerate(self._local(positions)):
            if looked % CHECK_EVERY_STATES == CHECK_EVERY_STATES - 1:
                check_stop(stop)
            if not test(vals):
                continue
            choices = []
            for k, w in writes:
                if w is None:
                    new: Iterable[int] = range(self.sizes[k])
                elif isinstance(w, tuple):
                    new = (combo[place[w[1]]],)
                else:
                    new = (w,)
                choices.append([(v - combo[place[k]]) * self.strides[k] for v in new])
            posts = sorted({offset + sum(deltas) for deltas in itertools.product(*choices)})
            yield positions, offset, posts

    # --- urgency ------------------------------------------------------------------------------
    # Every table below is built into locals and stored whole after the builder's last stop check
    # (`stopping.py`): a stopped build leaves the abstraction as it was.
    def urgent_after(self, stop: StopTest | None = None) -> list[int]:
        """Per abstract state, the model-order position of the first automatic transition certainly enabled
        there (len(automatic) when none): only automatics at or before it can fire."""
        if self._urgent_after is None:
            automatic = self.system.automatic
            urgent = [len(automatic)] * self.size
            for position in reversed(range(len(automatic))):
                check_stop(stop)
                certain = approximate(self.system.compiled.guard_of(automatic[position].source), self.keep, over=False)
                for x in self.states_where(certain):
                    urgent[x] = position
            self._urgent_after = urgent
        return self._urgent_after

    def threshold(self, t: CompiledTransition) -> int:
        """`t` may fire in abstract state x only if urgent_after()[x] >= threshold(t)."""
        position = self._automatic_position.get(t.number)
        return len(self.system.automatic) if position is None else position

    # --- distances --------------------------------------------------------------------------
    def cost(self, t: CompiledTransition) -> int:
        return 1 if self.costed is None or t.number in self.costed else 0

    def predecessors(self, stop: StopTest | None = None) -> tuple[list[list[int]], list[list[int]]]:
        """Backward adjacency over the relevant transitions (self-loops left out): (cost 1, cost 0) edges."""
        if self._predecessors is None:
            costly: list[list[int]] = [[] for _ in range(self.size)]
            free_edges: list[list[int]] = [[] for _ in range(self.size)]
            blocked = self.blocked
            urgent = self.urgent_after(stop)
            work = 0  # since the last stop check: candidate edges, and a local assignment costs as much as ~64
            for t in self.relevant:
                pred = costly if self.cost(t) else free_edges
                threshold = self.threshold(t)
                for outcome in range(len(t.outcomes)):
                    for positions, pre, posts in self._effects(t, outcome, TRUE, stop):
                        free = self.free_offsets(positions)
                        work += 64
                        for post in posts:
                            if post == pre:
                                continue
                            work += len(free)
                            if work >= CHECK_EVERY_STATES:
                                check_stop(stop)
                                work = 0
                            for f in free:
                                x, y = pre + f, post + f
                                if not blocked[x] and not blocked[y] and urgent[x] >= threshold:
                                    pred[y].append(x)
            self._predecessors = (costly, free_edges)
        return self._predecessors

    def successors(self, stop: StopTest | None = None) -> list[list[int]]:
        if self._successors is None:
            succ: list[list[int]] = [[] for _ in range(self.size)]
            for pred in self.predecessors(stop):
                for y, xs in enumerate(pred):
                    if y % CHECK_EVERY_STATES == 0:
                        check_stop(stop)
                    for x in xs:
                        succ[x].append(y)
            self._successors = succ
        return self._successors

    def reach_from_initial(self, stop: StopTest | None = None) -> None:
        """The states reachable from the model's initial state: most starts the controller plans from."""
        if self._initial_index is None:
            initial = self.index(self.system.compiled.initial())
            self.reach_from(initial, stop)
            self._initial_index = initial

    def covers(self, state: int) -> bool:
        """`reachable` already holds what `reach_from_initial` and `reach_from(state)` would add."""
        return self._initial_index is not None and bool(self.reachable[state] or self.blocked[state])

    def reach_from(self, state: int, stop: StopTest | None = None) -> bool:
        """Extend `reachable` by the abstract states reachable from `state`; True if it grew.

        Images of achievers are restricted to these: a plan only passes through states reachable from its
        start, and the guard of an achiever alone would allow combinations that never occur (a robot sent to
        one pose while standing three poses away).
        """
        if self.reachable[state] or self.blocked[state]:
            return False
        succ = self.successors(stop)
        reachable = bytearray(self.reachable)
        reachable[state] = 1
        frontier = [state]
        while frontier:
            check_stop(stop)
            following = []
            for x in frontier:
                for y in succ[x]:
                    if not reachable[y]:
                        reachable[y] = 1
                        following.append(y)
            frontier = following
        self.reachable, self.reachable_version = reachable, self.reachable_version + 1
        return True

    def _reachable_predecessors(self, stop: StopTest | None) -> tuple[list[list[int]], list[list[int]]]:
        """`predecessors` without the states no start reaches (rebuilt when the reachable set grows)."""
        if self._restricted_version != self.reachable_version:
            reachable = self.reachable
            restricted: list[list[list[int]]] = []
            for pred in self.predecessors(stop):
                kept: list[list[int]] = []
                work = 0
                for y, xs in enumerate(pred):
                    work += 1 + len(xs)
                    if work >= CHECK_EVERY_STATES:
                        check_stop(stop)
                        work = 0
                    kept.append([x for x in xs if reachable[x]] if reachable[y] else [])
                restricted.append(kept)
            self._restricted = (restricted[0], restricted[1])
            self._restricted_version = self.reachable_version
        return self._restricted

    def _condensed(self, stop: StopTest | None) -> tuple[list[int], list[list[int]], list[list[int]]]:
        """The reachable states with every strongly connected set of free (cost 0) edges merged into one node:
        (node of each state, -1 if unreachable; costly and free predecessor lists between nodes).

        Free edges abound (in a nutrunner's projection the robot's moves cost nothing) and mostly come in
        cycles; merging them makes each of the many distance tables of a projection cheap.
        """
        if self._condensed_version != self.reachable_version:
            costly, free = self._reachable_predecessors(stop)
            component = _components(self.reachable, free, stop)
            count = max(component, default=-1) + 1
            node_costly: list[set[int]] = [set() for _ in range(count)]
            node_free: list[set[int]] = [set() for _ in range(count)]
            for y, c in enumerate(component):
                if y % CHECK_EVERY_STATES == 0:
                    check_stop(stop)
                if c < 0:
                    continue
                for x in free[y]:
                    if component[x] != c:
                        node_free[c].add(component[x])
                for x in costly[y]:
                    if component[x] != c:
                        node_costly[c].add(component[x])
            check_stop(stop)
            self._condensation = (component, [list(n) for n in node_costly], [list(n) for n in node_free])
            self._condensed_version = self.reachable_version
        return self._condensation

    def distances(self, key: object, sources: Callable[[], Iterable[tuple[int, int]]],
                  stop: StopTest | None = None) -> list[int]:
        """Backward 0-1 breadth-first distances to goal states, each with its own initial cost.

        Only over the states reachable from the starts seen so far (`reach_from`): a path from such a
        state never leaves them, and most of the product of domains is never reached. Computed once per
        key and set of reachable states, on the condensed graph (`_condensed`).
        """
        key = (key, self.reachable_version)
        table = self._distances.get(key)
        if table is None:
            component, costly, free = self._condensed(stop)
            node_table = [INF] * len(costly)
            layers: dict[int, list[int]] = {}
            for n, (g, c) in enumerate(sources()):
                if n % CHECK_EVERY_STATES == 0:
                    check_stop(stop)
                node = component[g]
                if node >= 0 and c < node_table[node]:
                    node_table[node] = c
                    layers.setdefault(c, []).append(node)
            depth = min(layers, default=0)
            while layers:
                check_stop(stop)
                frontier = layers.pop(depth, [])
                following = layers.setdefault(depth + 1, [])
                i = 0
                while i < len(frontier):
                    if i % CHECK_EVERY_STATES == 0:
                        check_stop(stop)
                    y = frontier[i]
                    i += 1
                    if node_table[y] != depth:
                        continue  # reached more cheaply in the meantime
                    for x in free[y]:
                        if node_table[x] > depth:
                            node_table[x] = depth
                            frontier.append(x)
                    for x in costly[y]:
                        if node_table[x] > depth + 1:
                            node_table[x] = depth + 1
                            following.append(x)
                if not following:
                    del layers[depth + 1]
                depth += 1
            table = [INF if c < 0 else node_table[c] for c in component]
            if len(self._distances) > 256:
                self._distances.clear()
            self._distances[key] = table
        return table

    def enabled_states(self, t: CompiledTransition, outcome: int, condition: Predicate,
                       stop: StopTest | None = None) -> list[int]:
        """States where the abstract guard of (t, outcome) and `condition` can hold."""
        result: list[int] = []
        blocked, urgent, threshold = self.blocked, self.urgent_after(stop), self.threshold(t)
        for positions, pre, _ in self._effects(t, outcome, condition, stop):
            result.extend(
                x for x in (pre + f for f in self.free_offsets(positions)) if not blocked[x] and urgent[x] >= threshold
            )
        return result

    def firings(self, t: CompiledTransition, outcome: int, condition: Predicate,
                stop: StopTest | None = None) -> list[tuple[int, int]]:
        """(state before, state after) for every abstract firing of (t, outcome) where `condition` holds."""
        result: list[tuple[int, int]] = []
        blocked, urgent, threshold = self.blocked, self.urgent_after(stop), self.threshold(t)
        for positions, pre, posts in self._effects(t, outcome, condition, stop):
            free = self.free_offsets(positions)
            for post in posts:
                result.extend(
                    (pre + f, post + f) for f in free
                    if not blocked[pre + f] and not blocked[post + f] and urgent[pre + f] >= threshold
                )
        return result

    def images(self, t: CompiledTransition, outcome: int, condition: Predicate) -> set[int]:
        """States right after (t, outcome) fires where its guard and `condition` hold."""
        result: set[int] = set()
        blocked, urgent, threshold = self.blocked, self.urgent_after(), self.threshold(t)
        for positions, pre, posts in self._effects(t, outcome, condition):
            free = self.free_offsets(positions)
            for post in posts:
                result.update(
                    post + f for f in free
                    if not blocked[pre + f] and not blocked[post + f] and urgent[pre + f] >= threshold
                )
        return result


def _components(present: bytearray, edges: list[list[int]], stop: StopTest | None) -> list[int]:
    """Strongly connected components (iterative Tarjan) of the graph y -> edges[y] over `present` states;
    -1 for the others."""
    size = len(edges)
    component = [-1] * size
    index = [-1] * size
    low = [0] * size
    on_stack = bytearray(size)
    stack: list[int] = []
    counter = 0
    count = 0
    steps = 0  # of the depth-first walk: one stop check per CHECK_EVERY_STATES
    for root in range(size):
        if not present[root] or index[root] >= 0:
            continue
        work = [(root, 0)]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack[root] = 1
        while work:
            steps += 1
            if steps % CHECK_EVERY_STATES == 0:
                check_stop(stop)
            v, i = work[-1]
            successors = edges[v]
            if i < len(successors):
                work[-1] = (v, i + 1)
                w = successors[i]
                if not present[w]:
                    continue
                if index[w] < 0:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack[w] = 1
                    work.append((w, 0))
                elif on_stack[w] and index[w] < low[v]:
                    low[v] = index[w]
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                if low[v] < low[parent]:
                    low[parent] = low[v]
            if low[v] == index[v]:
                while True:
                    w = stack.pop()
                    on_stack[w] = 0
                    component[w] = count
                    if w == v:
                        break
                count += 1
    return component
