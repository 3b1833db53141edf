"""Variables: a path, a kind (measured / estimated / command) and a finite domain."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .predicates import Predicate

Value = bool | int | str
RESERVED_WORDS = frozenset({"true", "false", "in"})


class Kind(Enum):
    MEASURED = "measured"  # written only by a hub
    ESTIMATED = "estimated"  # written only by controller actions, persisted
    COMMAND = "command"  # written only by controller actions, sent to hubs


@dataclass(frozen=True)
class Domain:
    """A finite, ordered set of values: bools, enumeration names or a small int range."""

    values: tuple[Value, ...]

    @staticmethod
    def boolean() -> Domain:
        return BOOL

    @staticmethod
    def enum(*names: str) -> Domain:
        if not names:
            raise ValueError("an enumeration needs at least one name")
        for name in names:
            if not (isinstance(name, str) and name.isidentifier()) or name in RESERVED_WORDS:
                raise ValueError(f"enumeration value {name!r} is not an identifier (or is a reserved word)")
        if len(set(names)) != len(names):
            raise ValueError(f"enumeration {names} repeats a name")
        return Domain(tuple(names))

    @staticmethod
    def range(low: int, high: int) -> Domain:
        """The integers low..high, both included."""
        if high < low:
            raise ValueError(f"empty integer range {low}..{high}")
        return Domain(tuple(range(low, high + 1)))

    @property
    def is_bool(self) -> bool:
        return self.values == (False, True)

    def __contains__(self, value: object) -> bool:
        # bool is a subclass of int: True must not pass for 1 nor 1 for True.
        if isinstance(value, bool):
            return self.is_bool and value in self.values
        if self.is_bool:
            return False
        return value in self.values

    def index(self, value: Value) -> int:
        return self.values.index(value)

    def describe(self) -> str:
        if self.is_bool:
            return "bool"
        if all(isinstance(v, int) for v in self.values):
            return f"{self.values[0]}..{self.values[-1]}"
        return "{" + ", ".join(str(v) for v in self.values) + "}"


BOOL = Domain((False, True))


@dataclass(frozen=True, eq=False)
class Variable:
    """A state variable. `==`, `!=`, `&`, `|` and `~` build predicates over it."""

    path: str
    kind: Kind
    domain: Domain
    initial: Value
    description: str = field(default="", compare=False)

    @property
    def resource(self) -> str:
        return self.path.split(".", 1)[0]

    @property
    def name(self) -> str:
        return self.path.split(".", 1)[1]

    def __hash__(self) -> int:
        return hash(self.path)

    # Predicate construction. Variables are keyed by path everywhere else, so
    # overriding == for them does not disturb dicts or sets of paths.
    def __eq__(self, other: object) -> Predicate:  # type: ignore[override]  # == builds a predicate (the DSL)
        from .predicates import eq

        return eq(self.path, other)

    def __ne__(self, other: object) -> Predicate:  # type: ignore[override]  # != builds a predicate (the DSL)
        from .predicates import ne

        return ne(self.path, other)

    def is_in(self, *values: Value) -> Predicate:
        from .predicates import In

        return In(self.path, tuple(values))

    def _truth(self) -> Predicate:
        from .predicates import IsTrue

        return IsTrue(self.path)

    def __invert__(self) -> Predicate:
        return ~self._truth()

    def __and__(self, other: object) -> Predicate:
        return self._truth() & other

    def __rand__(self, other: object) -> Predicate:
        from .predicates import as_predicate

        return as_predicate(other) & self._truth()

    def __or__(self, other: object) -> Predicate:
        return self._truth() | other

    def __ror__(self, other: object) -> Predicate:
        from .predicates import as_predicate

        return as_predicate(other) | self._truth()

    def __repr__(self) -> str:
        return f"Variable({self.path}: {self.kind.value} {self.domain.describe()})"


def _initial(domain: Domain, initial: Value | None) -> Value:
    # Measured variables start unknown on the wire; the model assumes the
    # first value (false, the first name, the low bound) until measured.
    return domain.values[0] if initial is None else initial


def measured(path: str, domain: Domain = BOOL, initial: Value | None = None, description: str = "") -> Variable:
    return Variable(path, Kind.MEASURED, domain, _initial(domain, initial), description)


def estimated(path: str, domain: Domain = BOOL, initial: Value | None = None, description: str = "") -> Variable:
    return Variable(path, Kind.ESTIMATED, domain, _initial(domain, initial), description)


def command(path: str, domain: Domain = BOOL, initial: Value | None = None, description: str = "") -> Variable:
    return Variable(path, Kind.COMMAND, domain, _initial(domain, initial), description)
