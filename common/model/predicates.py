"""Predicates: boolean expressions over variables, in one notation both ways.

Notation (what `str()` prints and `parse_predicate` reads):
``true``, ``false``, ``a.b`` (a bool variable), ``a.b == v``, ``a.b != v``,
``a.b in {v, w}``, ``!p``, ``p && q``, ``p || q``, parentheses. A value is
``true``, ``false``, an integer or an enumeration name; a token with a dot is a
variable path, so ``ur.pos_m == ur.ref_c`` compares two variables.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from .variables import Value, Variable


@dataclass(frozen=True)
class Ref:
    """The value of another variable, on the right of == / != / :=."""

    path: str

    def __str__(self) -> str:
        return self.path


Operand = Value | Ref


def format_value(value: Operand) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def as_operand(value: object) -> Operand:
    if isinstance(value, Variable):
        return Ref(value.path)
    if isinstance(value, Ref | bool | int | str):
        return value
    raise TypeError(f"cannot compare a variable with {value!r}")


def operand_value(operand: Operand, state: Mapping[str, Value]) -> Value:
    return state[operand.path] if isinstance(operand, Ref) else operand


class Predicate:
    """Base of the predicate tree. Nodes are frozen dataclasses: equal when equal in structure."""

    precedence = 4  # atoms bind tightest; Not 3, And 2, Or 1

    def __and__(self, other: object) -> Predicate:
        return And((self, as_predicate(other)))

    def __rand__(self, other: object) -> Predicate:
        return And((as_predicate(other), self))

    def __or__(self, other: object) -> Predicate:
        return Or((self, as_predicate(other)))

    def __ror__(self, other: object) -> Predicate:
        return Or((as_predicate(other), self))

    def __invert__(self) -> Predicate:
        return Not(self)

    def __bool__(self) -> bool:
        raise TypeError("a predicate has no truth value of its own: use `&`, `|`, `~`, or evaluate it")

    def eval(self, state: Mapping[str, Value]) -> bool:
        raise NotImplementedError

    def paths(self) -> set[str]:
        raise NotImplementedError

    def operands(self) -> Iterable[tuple[str, Operand]]:
        """(variable path, compared value) pairs, for domain checks."""
        return ()


@dataclass(frozen=True)
class Const(Predicate):
    value: bool

    def eval(self, state: Mapping[str, Value]) -> bool:
        return self.value

    def paths(self) -> set[str]:
        return set()

    def __str__(self) -> str:
        return "true" if self.value else "false"


TRUE = Const(True)
FALSE = Const(False)


@dataclass(frozen=True)
class IsTrue(Predicate):
    """A bool variable used as a predicate."""

    path: str

    def eval(self, state: Mapping[str, Value]) -> bool:
        return state[self.path] is True

    def paths(self) -> set[str]:
        return {self.path}

    def operands(self) -> Iterable[tuple[str, Operand]]:
        return ((self.path, True),)

    def __str__(self) -> str:
        return self.path


@dataclass(frozen=True)
class Eq(Predicate):
    path: str
    value: Operand

    def eval(self, state: Mapping[str, Value]) -> bool:
        return state[self.path] == operand_value(self.value, state)

    def paths(self) -> set[str]:
        return {self.path} | ({self.value.path} if isinstance(self.value, Ref) else set())

    def operands(self) -> Iterable[tuple[str, Operand]]:
        return ((self.path, self.value),)

    def __str__(self) -> str:
        return f"{self.path} == {format_value(self.value)}"


@dataclass(frozen=True)
class Ne(Predicate):
    path: str
    value: Operand

    def eval(self, state: Mapping[str, Value]) -> bool:
        return state[self.path] != operand_value(self.value, state)

    def paths(self) -> set[str]:
        return {self.path} | ({self.value.path} if isinstance(self.value, Ref) else set())

    def operands(self) -> Iterable[tuple[str, Operand]]:
        return ((self.path, self.value),)

    def __str__(self) -> str:
        return f"{self.path} != {format_value(self.value)}"


@dataclass(frozen=True)
class In(Predicate):
    path: str
    values: tuple[Value, ...]

    def eval(self, state: Mapping[str, Value]) -> bool:
        return state[self.path] in self.values

    def paths(self) -> set[str]:
        return {self.path}

    def operands(self) -> Iterable[tuple[str, Operand]]:
        return ((self.path, v) for v in self.values)

    def __str__(self) -> str:
        return f"{self.path} in {{{', '.join(format_value(v) for v in self.values)}}}"


@dataclass(frozen=True)
class Not(Predicate):
    operand: Predicate
    precedence = 3

    def eval(self, state: Mapping[str, Value]) -> bool:
        return not self.operand.eval(state)

    def paths(self) -> set[str]:
        return self.operand.paths()

    def operands(self) -> Iterable[tuple[str, Operand]]:
        return self.operand.operands()

    def __str__(self) -> str:
        inner = str(self.operand)
        if isinstance(self.operand, IsTrue | Const | Not):
            return f"!{inner}"
        return f"!({inner})"


@dataclass(frozen=True)
class _Junction(Predicate):
    """What And and Or share: two or more operands, read alike."""

    items: tuple[Predicate, ...]

    def __post_init__(self) -> None:
        if len(self.items) < 2:
            raise ValueError(f"{type(self).__name__} needs at least two operands")

    def paths(self) -> set[str]:
        return set().union(*(p.paths() for p in self.items))

    def operands(self) -> Iterable[tuple[str, Operand]]:
        for p in self.items:
            yield from p.operands()


@dataclass(frozen=True)
class And(_Junction):
    precedence = 2

    def eval(self, state: Mapping[str, Value]) -> bool:
        return all(p.eval(state) for p in self.items)

    def __and__(self, other: object) -> Predicate:
        # a & b & c builds one flat And, as `a && b && c` parses.
        return And((*self.items, as_predicate(other)))

    def __str__(self) -> str:
        return " && ".join(_wrap(p, nested=And) for p in self.items)


@dataclass(frozen=True)
class Or(_Junction):
    precedence = 1

    def eval(self, state: Mapping[str, Value]) -> bool:
        return any(p.eval(state) for p in self.items)

    def __or__(self, other: object) -> Predicate:
        return Or((*self.items, as_predicate(other)))

    def __str__(self) -> str:
        return " || ".join(_wrap(p, nested=Or) for p in self.items)


def _wrap(child: Predicate, nested: type[_Junction]) -> str:
    # A child of the same connective keeps its parentheses so that printing and
    # parsing preserve the tree exactly: parse(str(p)) == p.
    if isinstance(child, nested) or child.precedence <= nested.precedence:
        return f"({child})"
    return str(child)


def as_predicate(value: object) -> Predicate:
    if isinstance(value, Predicate):
        return value
    if isinstance(value, Variable):
        return IsTrue(value.path)
    if isinstance(value, bool):
        return Const(value)
    if isinstance(value, str):
        from .parser import parse_predicate

        return parse_predicate(value)
    raise TypeError(f"not a predicate: {value!r}")


def eq(path: str, value: object) -> Predicate:
    return Eq(path, as_operand(value))


def ne(path: str, value: object) -> Predicate:
    return Ne(path, as_operand(value))


def all_of(*items: object) -> Predicate:
    """Conjunction of any number of predicates (true when empty)."""
    preds: list[Predicate] = []
    for item in items:
        p = as_predicate(item)
        if p != TRUE:
            preds.extend(p.items if isinstance(p, And) else (p,))
    if not preds:
        return TRUE
    return preds[0] if len(preds) == 1 else And(tuple(preds))


def any_of(*items: object) -> Predicate:
    """Disjunction of any number of predicates (false when empty)."""
    preds: list[Predicate] = []
    for item in items:
        p = as_predicate(item)
        if p != FALSE:
            preds.extend(p.items if isinstance(p, Or) else (p,))
    if not preds:
        return FALSE
    return preds[0] if len(preds) == 1 else Or(tuple(preds))
