"""Tour bounds: atoms reached by achievers that share one projection (see `heuristics` for the argument)."""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable, Sequence

from common.model import And, Predicate
from common.model.compiled import CompiledTransition, State, predicate_source

from .abstraction import INF, Abstraction, approximate
from .arborescence import min_arborescence
from .stopping import StopTest, check_stop

# Beyond this many classes the arborescence (Edmonds, per evaluation) costs more than it gains: with one
# atom per class the cheapest incoming edges already hold most of the tour.
MAX_CLASSES_FOR_ARBORESCENCE = 12
SUPER_ROOT = 1 << 32  # exceeds any tree's cost; far below INF

Achiever = tuple[CompiledTransition, int, Predicate]  # (transition, outcome, condition before it fires)


def generate(body: str) -> Callable[[State], object]:
    """A function of the state tuple `s` returning the generated expression `body`."""
    namespace: dict[str, object] = {}
    exec(f"def f(s):\n    return {body}", namespace)
    return namespace["f"]  # type: ignore[return-value]  # compiled by exec: the namespace holds objects


class TourGroup:
    """Atoms reached by achievers that share one projection (which leaves the atoms' variables out)."""

    def __init__(
        self,
        abstraction: Abstraction,
        atoms: Sequence[Predicate],
        achieved_by: Sequence[list[Achiever]],
        index: dict[str, int],
        costed: frozenset[int],
        arborescence: bool = True,
        potential: int = 1,
        stop: StopTest | None = None,
    ) -> None:
        """`costed`: the transitions this group counts (its share of the zero-one cost partition); `stop`
        ends the build (`stopping.Stopped`)."""
        self.abstraction = abstraction
        self.atoms = tuple(atoms)
        self.arborescence = arborescence
        self.potential = potential
        self.index = abstraction.index
        keep = abstraction.keep
        # Atoms whose achievers look the same in the projection form a class.
        by_signature: dict[frozenset[object], list[int]] = {}
        for n, found in enumerate(achieved_by):
            signature = frozenset(
                (str(approximate(And((abstraction.system.compiled.guard_of(t.source), c)), keep)),
                 tuple(str(a) for a in t.source.outcomes[o] if a.path in keep), t.number in costed)
                for t, o, c in found
            )
            by_signature.setdefault(signature, []).append(n)
        self.classes = list(by_signature.values())
        representative = [achieved_by[members[0]] for members in self.classes]
        self._fires: list[list[tuple[int, int]]] = []  # (state, cost) where an achiever of the class fires
        for found in representative:
            check_stop(stop)
            self._fires.append([(x, int(t.number in costed))
                                for t, o, c in found for x in abstraction.enabled_states(t, o, c, stop)])
        self._fires_keys = [  # distance tables are shared by every group over the same abstraction
            ("fires", frozenset((t.number, o, c, t.number in costed) for t, o, c in found)) for found in representative
        ]
        self.reach: list[list[int]] = []  # D_K: (counted) steps until an achiever of class K has fired
        size = len(self.classes)
        self._pairs: list[list[tuple[int, int]]] = []  # (before, after) an achiever of the class fires
        for found in representative:
            check_stop(stop)
            pairs: set[tuple[int, int]] = set()
            for t, o, c in found:
                pairs.update(abstraction.firings(t, o, c, stop))
            self._pairs.append(sorted(pairs))
        # One step achieving two atoms at once makes the segment between them empty.
        class_of = {n: k for k, members in enumerate(self.classes) for n in members}
        self._together: set[tuple[int, int]] = set()
        by_step: dict[tuple[int, int], list[int]] = {}
        for n, found in enumerate(achieved_by):
            for t, o, _ in found:
                by_step.setdefault((t.number, o), []).append(n)
        for atoms_of_step in by_step.values():
            for a, b in itertools.permutations(atoms_of_step, 2):
                self._together.add((class_of[a], class_of[b]))
        self.between = [[INF] * size for _ in range(size)]  # W(L, K): from just after L's achiever to K's
        self.reach_pi: list[list[int]] = []  # the same two with potentials (see `_potentials`)
        self.between_pi = [[INF] * size for _ in range(size)]
        self._version = -1
        unsat = [
            " + ".join(f"(not {predicate_source(atoms[n], index)})" for n in members) + " + 0"
            for members in self.classes
        ]
        self.counts = generate("(" + ", ".join(unsat) + ",)")
        self._cache: dict[tuple[int, tuple[int, ...]], list[tuple[tuple[int, ...], int]]] = {}
        self._values: dict[tuple[int, tuple[int, ...]], int] = {}

    def prepare(self, start: State, stop: StopTest | None = None) -> None:
        """Restrict the states after achievers to those reachable from the start (and earlier starts).
        The tables are computed first and stored together after the last stop check."""
        abstraction = self.abstraction
        abstraction.reach_from_initial(stop)
        abstraction.reach_from(self.index(start), stop)
        if self._version == abstraction.reachable_version:
            return
        reachable = abstraction.reachable
        reach = [
            abstraction.distances(key, functools.partial(_same, fires), stop)
            for key, fires in zip(self._fires_keys, self._fires, strict=True)
        ]
        pairs = [[(z, y) for z, y in found if reachable[z]] for found in self._pairs]
        between = []
        for found in pairs:
            check_stop(stop)
            between.append([min((to[y] for _, y in found), default=INF) for to in reach])
        for a, b in self._together:
            between[a][b] = 0
        reach_pi: list[list[int]] = []
        between_pi = self.between_pi
        if self.potential and len(self.atoms) > 1:  # potentials only shift costs between atoms
            reach_pi, between_pi = self._potentials(reach, pairs, stop)
        self.reach, self.between, self.reach_pi, self.between_pi = reach, between, reach_pi, between_pi
        self._version = abstraction.reachable_version
        self._cache.clear()
        self._values.clear()

    def ready_for(self, start: State) -> bool:
        """`prepare(start)` would build nothing."""
        return self.abstraction.covers(self.index(start)) and self._version == self.abstraction.reachable_version

    def _potentials(self, reach: list[list[int]], pairs: list[list[tuple[int, int]]],
                    stop: StopTest | None) -> tuple[list[list[int]], list[list[int]]]:
        """Edge costs shifted by potentials on the states where achievers fire.

        `W(L, K)` takes the best state after L's achiever, often one where work for the next segment is
        already done (the robot already sent on), which the segment before never paid for: summed over a
        tour the bound loses a step or two per atom. With any potential pi >= 0 on firing states, the
        path's cost telescopes into root edges `min_z (d(x, z) - pi(z))` and edges
        `min (pi(z) + d(after z, z') - pi(z'))`; the last atom's pi is dropped (>= 0). We give a firing
        state the steps (up to `potential`) its next segment saves over the class's best: ahead work then
        costs the same on both sides, so it is counted once.
        """
        abstraction, limit, size = self.abstraction, self.potential, len(self.classes)
        pis: list[dict[int, int]] = []
        varies = False
        for k, found in enumerate(pairs):
            check_stop(stop)
            out: dict[int, int] = {}
            for z, y in found:
                best = min((reach[j][y] for j in range(size) if j != k), default=INF)
                if best < out.get(z, INF + 1):
                    out[z] = best
            finite = [v for v in out.values() if v < INF]
            base = min(finite, default=INF)
            varies = varies or max(finite, default=INF) > base
            pis.append({z: min(limit, base + limit - v) for z, v in out.items() if v < INF and base + limit > v})
        if not varies:  # the same potential on every firing state of a class shifts nothing: skip the tables
            return [], self.between_pi
        keys = tuple(self._fires_keys)
        reach_pi = [
            abstraction.distances(("fires-pi", limit, k, keys), functools.partial(_reduced, fires, pi), stop)
            for k, (fires, pi) in enumerate(zip(self._fires, pis, strict=True))
        ]
        between_pi = []
        for pi, found in zip(pis, pairs, strict=True):
            check_stop(stop)
            between_pi.append([min((pi.get(z, 0) + to[y] for z, y in found), default=INF) for to in reach_pi])
        for a, b in self._together:
            between_pi[a][b] = min(between_pi[a][b], -limit)
        return reach_pi, between_pi

    def value(self, s: State) -> int:
        x = self.index(s)
        counts: tuple[int, ...] = self.counts(s)  # type: ignore[assignment]  # a generated function (exec) returns a tuple of counts
        key = (x, counts)
        value = self._values.get(key)
        if value is None:
            value = self._value(x, counts)
            if len(self._values) > 500_000:
                self._values.clear()
            self._values[key] = value
        return value

    def _value(self, x: int, counts: tuple[int, ...]) -> int:
        key = (x, tuple(c if c < 2 else 2 for c in counts))
        cached = self._cache.get(key)
        if cached is None:
            cached = [self._bound(x, key[1], self.reach, self.between)]
            if self.reach_pi:
                cached.append(self._bound(x, key[1], self.reach_pi, self.between_pi))
            if len(self._cache) > 200_000:
                self._cache.clear()
            self._cache[key] = cached
        best = 0
        for cheapest, rest in cached:
            if rest >= INF:
                return INF
            value = rest + sum(c * m for c, m in zip(counts, cheapest, strict=True))
            if value > best:
                best = value
        return best

    def _bound(
        self, x: int, counts: tuple[int, ...], reach: list[list[int]], between: list[list[int]]
    ) -> tuple[tuple[int, ...], int]:
        """(per-class cheapest edge from another atom, the rest of the bound): h = rest + sum(count * cheapest).

        The plan visits the atoms along a path from the start: one atom comes first (its edge is D from the
        start), every other atom has an incoming edge from an atom. For each class F that could hold the
        first atom: D_F(x) - cheapest_F + a minimum arborescence rooted at F over the classes, with edge
        costs reduced by the cheapest incoming edge; the least of these over F.
        """
        active = [k for k, c in enumerate(counts) if c]
        cheapest = [0] * len(counts)
        if not active:
            return tuple(cheapest), 0
        forced = -1  # a class whose atom no other atom can precede: it must come first
        for k in active:
            m = INF
            for j in active:
                if (j != k or counts[k] >= 2) and between[j][k] < m:
                    m = between[j][k]
            if m >= INF:
                if forced >= 0 or counts[k] >= 2:
                    return tuple(cheapest), INF
                forced = k
            else:
                cheapest[k] = m
        firsts = [forced] if forced >= 0 else active
        candidates = sorted((reach[f][x] - cheapest[f], f) for f in firsts if reach[f][x] < INF)
        if not candidates:
            return tuple(cheapest), INF
        if len(active) == 1 or not self.arborescence or len(active) > MAX_CLASSES_FOR_ARBORESCENCE:
            return tuple(cheapest), candidates[0][0]
        # One minimum arborescence instead of one per candidate F: a super-root (node 0) with an edge to each
        # candidate costing its start term plus a constant larger than any tree; the least tree then uses
        # exactly one super-root edge whenever a single first class can reach all the others.
        nodes = {k: n for n, k in enumerate(active, start=1)}
        edges = [(0, nodes[f], lower + SUPER_ROOT) for lower, f in candidates]
        edges += [
            (nodes[j], nodes[k], between[j][k] - cheapest[k])
            for j in active
            for k in active
            if j != k and between[j][k] < INF
        ]
        best = min_arborescence(len(active) + 1, 0, edges) - SUPER_ROOT
        if best >= SUPER_ROOT:
            best = INF  # no single first class reaches all the others
        return tuple(cheapest), best

    def __str__(self) -> str:
        return f"{len(self.atoms)} atom(s) in {len(self.classes)} class(es) over [{self.abstraction.describe()}]"


def _same(fires: list[tuple[int, int]]) -> list[tuple[int, int]]:
    return fires


def _reduced(fires: list[tuple[int, int]], pi: dict[int, int]) -> list[tuple[int, int]]:
    """Each firing state's cost less its potential (the work it may carry)."""
    return [(x, c - pi.get(x, 0)) for x, c in fires]
