"""Product variants: which operations an order requests, and the product variables an order owns.

A station model declares its **product variables** (glob patterns over estimated variables,
e.g. ``engine.*``; the operations' own states always belong to the product) and its
**variants**. A variant names the operations its orders request (all of them when it names
none) and its **parameters**: values of product variables that hold for the whole order, set
when the order starts (e.g. ``engine.count_bolts_e = 20``). The model's preconditions read them, so one
model serves every variant; an order may override a parameter's value, never add one.

A model with no variants has one implicit variant, ``default``: every operation, no parameters,
which is how a station without orders runs.

A variant's selection must be **sound**: an operation it keeps must not need the goal of one it
leaves out, since nothing would ever reach that goal. `selection_problems` finds a kept
operation whose precondition (with the variant's parameters in place) implies a left-out
operation's goal. The test is conservative: it reads the conjunctions of single-variable
comparisons in the precondition, so what it reports is certainly a problem, and a precondition
that hides the need in a disjunction passes unnoticed.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from fnmatch import fnmatchcase
from types import MappingProxyType

from .actions import Assign
from .operations import Operation
from .predicates import FALSE, TRUE, And, Const, Eq, In, IsTrue, Ne, Not, Or, Predicate, Ref
from .rewrite import after
from .variables import Kind, Value, Variable

DEFAULT_VARIANT = "default"


@dataclass(frozen=True)
class Variant:
    """A product variant: the operations its orders request (None: all) and its parameter values."""

    name: str
    operations: tuple[str, ...] | None = None
    parameters: Mapping[str, Value] = field(default_factory=lambda: MappingProxyType({}))
    description: str = ""

    def __post_init__(self) -> None:
        if self.operations is not None:
            object.__setattr__(self, "operations", tuple(self.operations))
        object.__setattr__(self, "parameters", MappingProxyType(dict(self.parameters)))

    def requested(self, operations: Iterable[Operation]) -> tuple[str, ...]:
        """The names of the operations an order of this variant requests, in the model's order."""
        names = [op.name for op in operations]
        if self.operations is None:
            return tuple(names)
        chosen = set(self.operations)
        return tuple(name for name in names if name in chosen)


def variant(name: str, operations: Iterable[str] | None = None, parameters: Mapping[str, Value] | None = None,
            description: str = "") -> Variant:
    return Variant(name, None if operations is None else tuple(operations), dict(parameters or {}), description)


def implicit_variant() -> Variant:
    """What a model without variants runs: every operation."""
    return Variant(DEFAULT_VARIANT)


def product_paths(patterns: Iterable[str], estimated: Iterable[Variable], operations: Iterable[Operation]) -> \
        tuple[str, ...]:
    """The product variables: the estimated variables matching a pattern, then every operation's state."""
    patterns = tuple(patterns)
    matched = tuple(v.path for v in estimated if any(fnmatchcase(v.path, p) for p in patterns))
    return (*matched, *(op.state_path for op in operations))


# --- soundness of a selection ----------------------------------------------------------------------

def _atom(predicate: Predicate, variables: Mapping[str, Variable]) -> tuple[str, frozenset[Value]] | None:
    """A comparison of one variable with constants as (path, the values that satisfy it); None otherwise."""
    negated = isinstance(predicate, Not)
    inner = predicate.operand if isinstance(predicate, Not) else predicate
    allowed: tuple[str, frozenset[Value]] | None = None
    if isinstance(inner, IsTrue):
        allowed = (inner.path, frozenset({True}))
    elif isinstance(inner, Eq | Ne) and not isinstance(inner.value, Ref):
        variable = variables.get(inner.path)
        if variable is None:
            return None
        if isinstance(inner, Eq):
            allowed = (inner.path, frozenset({inner.value}))
        else:
            allowed = (inner.path, frozenset(set(variable.domain.values) - {inner.value}))
    elif isinstance(inner, In):
        allowed = (inner.path, frozenset(inner.values))
    if allowed is None or not negated:
        return allowed
    variable = variables.get(allowed[0])
    if variable is None:
        return None
    return allowed[0], frozenset(set(variable.domain.values) - allowed[1])


def _conjuncts(predicate: Predicate) -> tuple[Predicate, ...]:
    return predicate.items if isinstance(predicate, And) else (predicate,)


def implies(premise: Predicate, conclusion: Predicate, variables: Mapping[str, Variable]) -> bool:
    """True only when `premise` certainly implies `conclusion` (a conservative test: see the module)."""
    if conclusion == TRUE or premise == Const(False):
        return True
    known: dict[str, frozenset[Value]] = {}
    for item in _conjuncts(premise):
        atom = _atom(item, variables)
        if atom is not None:
            path, values = atom
            known[path] = known[path] & values if path in known else values
    return all(_holds(item, known, variables) for item in _conjuncts(conclusion))


def _holds(item: Predicate, known: Mapping[str, frozenset[Value]], variables: Mapping[str, Variable]) -> bool:
    if item == TRUE:
        return True
    if isinstance(item, Or):
        return any(_holds(option, known, variables) for option in item.items)
    atom = _atom(item, variables)
    if atom is None or atom[0] not in known:
        return False
    path, values = atom
    return known[path] <= values


def selection_problems(chosen: Variant, operations: tuple[Operation, ...], variables: Mapping[str, Variable],
                       constants: Mapping[str, Value]) -> list[tuple[str, str]]:
    """(where, why) for each kept operation that needs a left-out operation's goal, or can never start.

    `constants`: the values of the variables no transition writes, as an order of this variant starts
    with them (initial values, the variant's parameters): they hold through the whole order."""
    if chosen.operations is None:
        return []
    kept = set(chosen.operations)
    left_out = [op for op in operations if op.name not in kept]
    fixed = tuple(Assign(path, value) for path, value in {**constants, **chosen.parameters}.items())
    problems = []
    for op in operations:
        if op.name not in kept:
            continue
        pre = after(op.pre, fixed)
        if pre == FALSE:
            problems.append((f"variant {chosen.name}", f"operation {op.name} can never start: its precondition is "
                                                       f"false with the values the variant holds constant"))
            continue
        for other in left_out:
            if implies(pre, other.goal, variables):
                problems.append((f"variant {chosen.name}",
                                 f"operation {op.name} needs the goal of {other.name}, which the variant leaves out: "
                                 f"nothing would reach {other.goal}, so {op.name} would never start"))
    return problems


def variant_problems(variants: tuple[Variant, ...], patterns: tuple[str, ...], operations: tuple[Operation, ...],
                     variables: Mapping[str, Variable], written: set[str]) -> list[tuple[str, str]]:
    """(where, why) for every problem of the model's variants and product patterns.

    `written`: the variables some transition of the model writes; a parameter must not be one
    of them, as it holds for the whole order (and the soundness test relies on it)."""
    problems: list[tuple[str, str]] = []
    seen: set[str] = set()
    names = {op.name for op in operations}
    estimated = [v for v in variables.values() if v.kind is Kind.ESTIMATED and not v.path.startswith("op.")]
    product_set = set(product_paths(patterns, estimated, operations))
    for pattern in patterns:
        if not any(fnmatchcase(v.path, pattern) for v in estimated):
            problems.append((f"product {pattern}", "matches no estimated variable of the model"))
    for chosen in variants:
        where = f"variant {chosen.name}"
        if chosen.name in seen:
            problems.append((where, "duplicate variant name"))
        seen.add(chosen.name)
        if not chosen.name.isidentifier():
            problems.append((where, "a variant's name must be an identifier (it is typed in hubs.toml and hubctl)"))
        for name in chosen.operations or ():
            if name not in names:
                problems.append((where, f"unknown operation {name}"))
        if chosen.operations is not None and len(set(chosen.operations)) != len(chosen.operations):
            problems.append((where, "names an operation twice"))
        for path, value in chosen.parameters.items():
            variable = variables.get(path)
            if variable is None or path not in product_set:
                problems.append((where, f"parameter {path} is not a product variable of the model"))
            elif value not in variable.domain:
                problems.append((where, f"parameter {path} = {value!r} is outside {variable.domain.describe()}"))
            elif path in written:
                problems.append((where, f"parameter {path} is written by a transition: a parameter holds for the "
                                        f"whole order"))
    if not problems:
        constants = {path: variables[path].initial for path in product_set
                     if path not in written and not path.startswith("op.")}
        for chosen in variants:
            problems += selection_problems(chosen, operations, variables, constants)
    return problems
