"""Can a predicate hold? A search over the variables' finite domains, for checks made before a run.

The search assigns one variable at a time and folds the predicate (`rewrite.after`), so a
conjunction that some atom makes false is dropped at once: guards of a few atoms answer after
a handful of steps. Reachability is not asked: a state that satisfies the predicate may be one
the station never reaches.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

from .actions import Assign
from .predicates import And, Const, Eq, In, IsTrue, Ne, Not, Or, Predicate, Ref
from .rewrite import after, simplify
from .variables import Domain, Value

DEFAULT_BUDGET = 20_000  # assignments tried before the search gives up undecided


@dataclass(frozen=True)
class Satisfiability:
    """`witness`: values of the predicate's variables under which it holds; None when none was found.
    `decided` is False when the budget ran out first (the predicate may or may not hold)."""

    witness: dict[str, Value] | None
    decided: bool = True

    @property
    def possible(self) -> bool:
        """It holds in some state, or the search could not rule that out."""
        return self.witness is not None or not self.decided


def satisfiable(predicate: Predicate, domains: Mapping[str, Domain], *, budget: int = DEFAULT_BUDGET) -> Satisfiability:
    search = _Search(domains, budget)
    witness = search.run(simplify(predicate), {})
    return Satisfiability(witness, decided=witness is not None or not search.exhausted)


class _Search:
    def __init__(self, domains: Mapping[str, Domain], budget: int) -> None:
        self.domains = domains
        self.left = budget
        self.exhausted = False

    def run(self, predicate: Predicate, chosen: dict[str, Value]) -> dict[str, Value] | None:
        if isinstance(predicate, Const):
            return dict(chosen) if predicate.value else None
        path, values = self._branch(predicate)
        for value in values:
            if self.left <= 0:
                self.exhausted = True
                return None
            self.left -= 1
            found = self.run(after(predicate, (Assign(path, value),)), {**chosen, path: value})
            if found is not None:
                return found
        return None

    def _branch(self, predicate: Predicate) -> tuple[str, tuple[Value, ...]]:
        """The variable to assign next and the values worth trying: a conjunction's atoms say which
        values of their variable can hold (`x == v` leaves one), so the most constrained goes first."""
        allowed: dict[str, tuple[Value, ...]] = {}
        for item in predicate.items if isinstance(predicate, And) else (predicate,):
            atom = _atom(item)
            if atom is None:
                continue
            path, accepts = atom
            values = allowed.get(path, self.domains[path].values)
            allowed[path] = tuple(v for v in values if accepts(v))
        if allowed:
            path = min(allowed, key=lambda p: len(allowed[p]))
            return path, allowed[path]
        path = _first_path(predicate)
        return path, self.domains[path].values


def _same(a: object, b: object) -> bool:
    return a == b and type(a) is type(b)  # True is not 1 here, as in the model's domains


def _atom(p: Predicate) -> tuple[str, Callable[[Value], bool]] | None:
    """A literal on one variable compared with constants: its path and which values satisfy it."""
    negated = isinstance(p, Not)
    inner = p.operand if isinstance(p, Not) else p
    test: Callable[[Value], bool]
    if isinstance(inner, IsTrue):
        path, test = inner.path, lambda v: v is True
    elif isinstance(inner, Eq | Ne) and not isinstance(inner.value, Ref):
        constant, equal = inner.value, isinstance(inner, Eq)
        path, test = inner.path, lambda v: _same(v, constant) == equal
    elif isinstance(inner, In):
        members = inner.values
        path, test = inner.path, lambda v: any(_same(v, m) for m in members)
    else:
        return None
    return (path, (lambda v: not test(v)) if negated else test)


def _first_path(predicate: Predicate) -> str:
    """The leftmost variable: with no literal to go by, decide the first atom as it is written."""
    if isinstance(predicate, IsTrue | In | Eq | Ne):
        return predicate.path
    if isinstance(predicate, Not):
        return _first_path(predicate.operand)
    if isinstance(predicate, And | Or):
        return _first_path(predicate.items[0])
    raise TypeError(f"no variable in {predicate!r}")
