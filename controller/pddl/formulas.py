"""Predicates as positive formulas over (variable, value) facts, and predicates regressed through actions.

PDDL has no finite-domain variables: a variable `x` with domain {a, b, c} becomes three facts
`x=a`, `x=b`, `x=c`, exactly one of them true. Over such facts every predicate of the model
has a negation-free form: `x != a` is `x=b or x=c`. Keeping formulas free of negation lets
the encoding use derived predicates only positively, which Fast Downward's translator handles
without computing negated axioms, and keeps relaxation heuristics admissible.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from common.model.actions import Assign
from common.model.compiled import CompiledModel
from common.model.predicates import FALSE, TRUE, And, Const, Eq, In, IsTrue, Ne, Not, Operand, Or, Predicate, Ref
from common.model.variables import Value


class Unexpressible(ValueError):
    """The model uses a construct the PDDL encoding cannot express; the message names it."""


@dataclass(frozen=True)
class Fact:
    """`variable == value`: one PDDL fact."""

    path: str
    value: Value


@dataclass(frozen=True)
class Other:
    """The variable of `fact` has another value: one derived fact instead of a disjunction over the domain
    each time (a robot's pose has tens of values, and synthesized guards say `pos != p` often)."""

    fact: Fact


@dataclass(frozen=True)
class Named:
    """A formula under a name: a derived predicate where the output has them, else written in place."""

    name: str
    formula: Formula


@dataclass(frozen=True)
class AllOf:
    items: tuple[Formula, ...]


@dataclass(frozen=True)
class AnyOf:
    items: tuple[Formula, ...]


Formula = Fact | Other | AllOf | AnyOf | Named
ALWAYS = AllOf(())
NEVER = AnyOf(())


def all_of(items: list[Formula]) -> Formula:
    flat: dict[Formula, None] = {}  # ordered, and no quadratic search for duplicates
    for item in items:
        if item == NEVER:
            return NEVER
        flat.update(dict.fromkeys(item.items if isinstance(item, AllOf) else (item,)))
    return next(iter(flat)) if len(flat) == 1 else AllOf(tuple(flat))


def any_of(items: list[Formula]) -> Formula:
    flat: dict[Formula, None] = {}
    for item in items:
        if item == ALWAYS:
            return ALWAYS
        flat.update(dict.fromkeys(item.items if isinstance(item, AnyOf) else (item,)))
    return next(iter(flat)) if len(flat) == 1 else AnyOf(tuple(flat))


class Facts:
    """The finite domains of a compiled model, and predicates over them turned into formulas."""

    def __init__(self, compiled: CompiledModel) -> None:
        self.domains: dict[str, tuple[Value, ...]] = {
            path: domain.values for path, domain in zip(compiled.paths, compiled.domains, strict=True)}

    def values(self, path: str, where: str) -> tuple[Value, ...]:
        try:
            return self.domains[path]
        except KeyError:
            raise Unexpressible(f"{where}: variable {path!r} is not a variable of the model") from None

    def is_value(self, path: str, value: Value, where: str) -> Formula:
        # `True in (0, 1)` is true in Python: compare by type as the model's domains do.
        same = [v for v in self.values(path, where) if v == value and type(v) is type(value)]
        return Fact(path, same[0]) if same else NEVER

    def other(self, fact: Formula) -> Formula:
        """Not `fact`: for a variable of two values, the other value's fact."""
        if not isinstance(fact, Fact):
            return ALWAYS if fact == NEVER else NEVER
        rest = [v for v in self.domains[fact.path] if Fact(fact.path, v) != fact]
        if len(rest) == 1:
            return Fact(fact.path, rest[0])
        return Other(fact) if rest else NEVER

    def equal(self, left: str, right: str, where: str) -> Formula:
        common = [v for v in self.values(left, where) if v in self.values(right, where)]
        return any_of([all_of([Fact(left, v), Fact(right, v)]) for v in common])

    def formula(self, predicate: Predicate, where: str, positive: bool = True) -> Formula:
        """The predicate (its negation if not `positive`) as a negation-free formula over facts."""
        p = predicate
        if isinstance(p, Const):
            return ALWAYS if p.value == positive else NEVER
        if isinstance(p, IsTrue):
            return self.formula(Eq(p.path, True), where, positive)
        if isinstance(p, Eq | Ne):
            holds = positive if isinstance(p, Eq) else not positive
            if isinstance(p.value, Ref):
                if holds:
                    return self.equal(p.path, p.value.path, where)
                return any_of([all_of([Fact(p.path, v), self.formula(Eq(p.value.path, v), where, False)])
                               for v in self.values(p.path, where)])
            if not isinstance(p.value, bool | int | str):
                raise Unexpressible(f"{where}: the predicate {p} compares with {p.value!r}, neither a value nor a "
                                    f"variable")
            fact = self.is_value(p.path, p.value, where)
            if holds:
                return fact
            return ALWAYS if fact == NEVER else self.other(fact)
        if isinstance(p, In):
            chosen = [self.formula(Eq(p.path, v), where) for v in p.values]
            if positive:
                return any_of(chosen)
            rest = [Fact(p.path, v) for v in self.values(p.path, where) if Fact(p.path, v) not in chosen]
            kept = [f for f in chosen if isinstance(f, Fact)]
            # Not any of a few values: each another value; not any of many: one of the few left.
            return all_of([self.other(f) for f in kept]) if len(kept) < len(rest) else any_of(list(rest))
        if isinstance(p, Not):
            return self.formula(p.operand, where, not positive)
        if isinstance(p, And | Or):
            parts = [self.formula(i, where, positive) for i in p.items]
            return all_of(parts) if isinstance(p, And) == positive else any_of(parts)
        raise Unexpressible(f"{where}: the predicate node {type(p).__name__} ({p}) has no PDDL encoding")


def _term(operand: Operand, substitution: Mapping[str, Operand]) -> Operand:
    return substitution.get(operand.path, operand) if isinstance(operand, Ref) else operand


def _compare(left: Operand, right: Operand, equal: bool) -> Predicate:
    if isinstance(left, Ref):
        if isinstance(right, Ref) and right.path == left.path:
            return TRUE if equal else FALSE
        return Eq(left.path, right) if equal else Ne(left.path, right)
    if isinstance(right, Ref):
        return _compare(right, left, equal)
    same = left == right and type(left) is type(right)
    return TRUE if same == equal else FALSE


def fold(items: tuple[Predicate, ...], conjunction: bool) -> Predicate:
    """And (or Or) of the items with constants folded: most guards regressed through a command become constant."""
    kept = []
    for item in items:
        if isinstance(item, Const):
            if item.value != conjunction:
                return item
            continue
        kept.append(item)
    if not kept:
        return Const(conjunction)
    if len(kept) == 1:
        return kept[0]
    return And(tuple(kept)) if conjunction else Or(tuple(kept))


def regress(predicate: Predicate, actions: tuple[Assign, ...]) -> Predicate:
    """The predicate that holds before the (simultaneous) assignments exactly when `predicate` holds after."""
    substitution: dict[str, Operand] = {a.path: a.value for a in actions}

    def go(p: Predicate) -> Predicate:
        if isinstance(p, Const):
            return p
        if isinstance(p, IsTrue):
            return _compare(_term(Ref(p.path), substitution), True, True)
        if isinstance(p, Eq | Ne):
            return _compare(_term(Ref(p.path), substitution), _term(p.value, substitution), isinstance(p, Eq))
        if isinstance(p, In):
            left = _term(Ref(p.path), substitution)
            if isinstance(left, Ref):
                return In(left.path, p.values)
            return TRUE if any(left == v and type(left) is type(v) for v in p.values) else FALSE
        if isinstance(p, Not):
            inner = go(p.operand)
            return Const(not inner.value) if isinstance(inner, Const) else Not(inner)
        if isinstance(p, And | Or):
            return fold(tuple(go(i) for i in p.items), isinstance(p, And))
        raise Unexpressible(f"the predicate node {type(p).__name__} ({p}) has no PDDL encoding")

    return go(predicate)
