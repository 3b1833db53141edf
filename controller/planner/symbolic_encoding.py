"""The bits of a symbolic search: the BDD backend, each variable as a bit vector, predicates and
transitions of a compiled model as BDDs over those bits (see `symbolic.py` for the search)."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from common.model import Predicate
from common.model.compiled import CompiledModel, CompiledTransition, State
from common.model.predicates import And, Const, Eq, In, IsTrue, Ne, Not, Or, Ref
from common.model.variables import Value

try:  # CUDD is ~100x faster; the pure-Python engine keeps the member usable where the wheel is missing.
    from dd import cudd as _dd

    BACKEND = "cudd"
except ImportError:  # pragma: no cover - depends on the platform's wheel
    from dd import autoref as _dd

    BACKEND = "autoref"

Function = Any  # dd.cudd.Function or dd.autoref.Function: the two share the operators used here


class Encoding:
    """Bits for the variables of a compiled model, and predicates translated into BDDs over them."""

    def __init__(self, compiled: CompiledModel, primed: set[int], order: Sequence[int]) -> None:
        """`primed`: the variables that get a primed copy; `order`: every variable once, top first."""
        self.compiled = compiled
        self.bdd = _dd.BDD()
        self.bdd.configure(reordering=False)
        self.bits: list[tuple[str, ...]] = []
        self.primes: dict[int, tuple[str, ...]] = {}
        for i, domain in enumerate(compiled.domains):
            width = math.ceil(math.log2(len(domain.values))) if len(domain.values) > 1 else 0
            self.bits.append(tuple(f"v{i}_{b}" for b in range(width)))
            if i in primed:
                self.primes[i] = tuple(f"{name}'" for name in self.bits[i])
        names: list[str] = []
        for i in order:
            for position, bit in enumerate(self.bits[i]):
                names.append(bit)
                # A primed bit sits next to its bit: renaming keeps the order, so it is a copy, not a rebuild.
                if i in self.primes:
                    names.append(self.primes[i][position])
        self.bdd.declare(*names)
        self.true: Function = self.bdd.true
        self.false: Function = self.bdd.false
        self._cubes: list[list[Function]] = [
            [self._code(self.bits[i], k) for k in range(len(d.values))] for i, d in enumerate(compiled.domains)
        ]
        self._primed_cubes: dict[int, list[Function]] = {
            i: [self._code(bits, k) for k in range(len(compiled.domains[i].values))] for i, bits in self.primes.items()
        }
        self.valid: Function = self.true
        for i in range(len(compiled.domains)):
            self.valid &= self.where(i, lambda v: True)
        self._memo: dict[Predicate, Function] = {}

    def _code(self, bits: Sequence[str], k: int) -> Function:
        u = self.true
        for position, name in enumerate(bits):
            bit = self.bdd.var(name)
            u &= bit if (k >> (len(bits) - 1 - position)) & 1 else ~bit
        return u

    # --- values and states ----------------------------------------------------------------------
    def value(self, i: int, value: Value, primed: bool = False) -> Function:
        """Variable i holds `value` (compared as the compiled guards compare: Python ==)."""
        return self.where(i, lambda v: v == value, primed)

    def where(self, i: int, test: Callable[[Value], bool], primed: bool = False) -> Function:
        cubes = self._primed_cubes[i] if primed else self._cubes[i]
        u = self.false
        for k, v in enumerate(self.compiled.domains[i].values):
            if test(v):
                u |= cubes[k]
        return u

    def equal(self, i: int, j: int, primed_i: bool = False) -> Function:
        """Variables i and j hold equal values (value equality: their domains may differ)."""
        u = self.false
        cubes_i = self._primed_cubes[i] if primed_i else self._cubes[i]
        for ki, vi in enumerate(self.compiled.domains[i].values):
            for kj, vj in enumerate(self.compiled.domains[j].values):
                if vi == vj:  # as the compiled guards compare
                    u |= cubes_i[ki] & self._cubes[j][kj]
        return u

    def state(self, state: State) -> Function:
        assignment: dict[str, bool] = {}
        for i, value in enumerate(state):
            domain = self.compiled.domains[i]
            if value not in domain:
                raise ValueError(f"{self.compiled.paths[i]} = {value!r} is outside its domain {domain.describe()}")
            k = _index(domain.values, value)
            bits = self.bits[i]
            for position, name in enumerate(bits):
                assignment[name] = bool((k >> (len(bits) - 1 - position)) & 1)
        return self.bdd.cube(assignment)

    def decode(self, assignment: dict[str, bool]) -> State:
        values: list[Value] = []
        for i, bits in enumerate(self.bits):
            k = 0
            for name in bits:
                k = (k << 1) | int(assignment.get(name, False))
            domain = self.compiled.domains[i].values
            if k >= len(domain):
                raise AssertionError(f"invalid code {k} for {self.compiled.paths[i]}: a set held an invalid state")
            values.append(domain[k])
        return tuple(values)

    def least(self, u: Function) -> State:
        """The state of `u` whose bits, in variable order, are the smallest: a choice that depends on `u` alone.

        Walks down by cofactors (not by node children) so that complemented edges, which the
        backends represent differently, need no special case."""
        assignment: dict[str, bool] = {}
        bdd, false = self.bdd, self.false
        while u != self.true:
            name = u.var
            low = bdd.let({name: False}, u)
            if low != false:
                assignment[name] = False
                u = low
            else:
                assignment[name] = True
                u = bdd.let({name: True}, u)
        return self.decode(assignment)

    # --- predicates -----------------------------------------------------------------------------
    def predicate(self, p: Predicate) -> Function:
        found = self._memo.get(p)
        if found is None:
            found = self._memo[p] = self._translate(p)
        return found

    def _translate(self, p: Predicate) -> Function:
        index = self.compiled.index
        if isinstance(p, Const):
            return self.true if p.value else self.false
        if isinstance(p, IsTrue):
            return self.where(index[p.path], lambda v: v is True)
        if isinstance(p, Eq | Ne):
            i = index[p.path]
            if isinstance(p.value, Ref):
                j = index[p.value.path]
                same = self.equal(i, j)
                return same if isinstance(p, Eq) else self.where(i, lambda v: True) & self.where(
                    j, lambda v: True) & ~same
            c = p.value
            return self.where(i, (lambda v: v == c) if isinstance(p, Eq) else (lambda v: v != c))
        if isinstance(p, In):
            options = p.values
            return self.where(index[p.path], lambda v: v in options)
        if isinstance(p, Not):
            # Sets hold valid codes only, so the invalid codes a negation lets in never matter.
            return ~self.predicate(p.operand)
        if isinstance(p, And):
            u = self.true
            for item in p.items:
                u &= self.predicate(item)
            return u
        if isinstance(p, Or):
            u = self.false
            for item in p.items:
                u |= self.predicate(item)
            return u
        raise TypeError(f"unknown predicate node {p!r}")

    def guard(self, t: CompiledTransition) -> Function:
        return self.predicate(self.compiled.guard_of(t.source))

    # --- assignments ----------------------------------------------------------------------------
    def substitution(self, t: CompiledTransition, outcome: int) -> dict[str, Function]:
        """Each bit the outcome writes, as a function of the state before (for composition: races, predecessors)."""
        compiled = self.compiled
        result: dict[str, Function] = {}
        for action in t.source.outcomes[outcome]:
            i = compiled.index[action.path]
            domain = compiled.domains[i].values
            bits = self.bits[i]
            if isinstance(action.value, Ref):
                j = compiled.index[action.value.path]
                for position, name in enumerate(bits):
                    mask = 1 << (len(bits) - 1 - position)
                    result[name] = self.where(j, functools.partial(_has_bit, domain, mask))
            else:
                k = _index(domain, action.value)
                for position, name in enumerate(bits):
                    result[name] = self.true if (k >> (len(bits) - 1 - position)) & 1 else self.false
        return result

    def compose(self, u: Function, substitution: dict[str, Function]) -> Function:
        return self.bdd.let(substitution, u) if substitution else u


def _index(domain: tuple[Value, ...], value: Value) -> int:
    # Domain.index would take True for 1: a stored value keeps its type.
    for k, v in enumerate(domain):
        if v == value and isinstance(v, bool) == isinstance(value, bool):
            return k
    raise ValueError(f"{value!r} is not in the domain {domain}")


def disjunction(items: Iterable[Function], false: Function) -> Function:
    """OR of many BDDs pairwise, as a balanced tree: a running union would be rebuilt once per item."""
    level = list(items)
    if not level:
        return false
    while len(level) > 1:
        level = [level[k] | level[k + 1] if k + 1 < len(level) else level[k] for k in range(0, len(level), 2)]
    return level[0]


def and_exists(bdd: Any, u: Function, v: Function, names: tuple[str, ...]) -> Function:
    if not names:
        return u & v
    if BACKEND == "cudd":
        return _dd.and_exists(u, v, names)  # one pass: the conjunction is never built whole
    return bdd.exist(names, u & v)


def variable_order(compiled: CompiledModel, written: set[int]) -> list[int]:
    """Variables no move writes first, then model order (a resource's variables together).

    A constant below varying variables costs one node per distinct sub-function above it; on top
    it costs one node per bit. Halved the layers of the reference station. Measured and dropped:
    interleaving a command with its measurement (ur.ref_pos_c, ur.pos_m) made the images many
    times slower, and sorting resources by how many guards read them gained nothing overall."""
    n = len(compiled.paths)
    return [i for i in range(n) if i not in written] + [i for i in range(n) if i in written]


def _has_bit(domain: tuple[Value, ...], mask: int, value: Value) -> bool:
    """Whether the index of `value` in `domain` has the bit `mask` set."""
    return bool(_index(domain, value) & mask)
