"""The Model: resources, global estimated variables, tracking abilities, operations, specifications.

Building a Model validates it and reports every problem at once (`ModelError`),
each with the variable path and the offending expression.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from functools import cached_property

from .abilities import Ability
from .operations import Operation, Specification
from .predicates import Predicate, Ref
from .resource import Resource
from .transitions import Transition, TransitionKind
from .variables import Kind, Value, Variable
from .variants import Variant, implicit_variant, product_paths, variant_problems


@dataclass(frozen=True)
class Problem:
    where: str  # the transition, operation, spec or variable it concerns
    message: str
    expression: str = ""

    def __str__(self) -> str:
        return f"{self.where}: {self.message}" + (f"\n    in: {self.expression}" if self.expression else "")


class ModelError(ValueError):
    def __init__(self, model_name: str, problems: list[Problem]) -> None:
        self.problems = problems
        lines = "\n".join(f"  - {p}" for p in problems)
        super().__init__(f"model {model_name!r} has {len(problems)} problem(s):\n{lines}")


@dataclass
class Model:
    name: str
    resources: tuple[Resource, ...]
    estimated: tuple[Variable, ...] = ()
    tracking: tuple[Ability, ...] = ()
    operations: tuple[Operation, ...] = ()
    specifications: tuple[Specification, ...] = ()
    validate_on_init: bool = field(default=True, repr=False)
    # Production (common/model/variants.py): patterns of the estimated variables that belong to the
    # product, and the variants an order may ask for (none: one implicit variant, every operation).
    product: tuple[str, ...] = ()
    variants: tuple[Variant, ...] = ()

    def __post_init__(self) -> None:
        self.resources = tuple(self.resources)
        self.estimated = tuple(self.estimated)
        self.tracking = tuple(self.tracking)
        self.operations = tuple(self.operations)
        self.specifications = tuple(self.specifications)
        self.product = tuple(self.product)
        self.variants = tuple(self.variants)
        if self.validate_on_init:
            problems = self.problems()
            if problems:
                raise ModelError(self.name, problems)

    # --- structure -----------------------------------------------------------------
    @cached_property
    def variables(self) -> dict[str, Variable]:
        result: dict[str, Variable] = {}
        for v in self._all_variables():
            result.setdefault(v.path, v)
        return result

    def _all_variables(self) -> list[Variable]:
        found = [v for r in self.resources for v in r.variables]
        found += list(self.estimated)
        found += [op.state_variable() for op in self.operations]
        return found

    @cached_property
    def abilities(self) -> tuple[Ability, ...]:
        return tuple(a for r in self.resources for a in r.abilities) + self.tracking

    @cached_property
    def ability_transitions(self) -> tuple[Transition, ...]:
        return tuple(t for a in self.abilities for t in a.transitions)

    @cached_property
    def operation_transitions(self) -> tuple[Transition, ...]:
        return tuple(t for op in self.operations for t in (op.start_transition(), op.finish_transition()))

    @cached_property
    def transitions(self) -> tuple[Transition, ...]:
        return self.operation_transitions + self.ability_transitions

    @cached_property
    def transition_by_name(self) -> dict[str, Transition]:
        return {t.name: t for t in self.transitions}

    @cached_property
    def operation_by_name(self) -> dict[str, Operation]:
        return {op.name: op for op in self.operations}

    @cached_property
    def resource_by_name(self) -> dict[str, Resource]:
        return {r.name: r for r in self.resources}

    @cached_property
    def product_variables(self) -> tuple[str, ...]:
        """The variables an order owns: the estimated ones `product` names, then every operation's state.
        They are archived with the order when the product leaves and return to their initial values."""
        estimated = [v for v in self._all_variables() if v.kind is Kind.ESTIMATED and not v.path.startswith("op.")]
        return product_paths(self.product, estimated, self.operations)

    @cached_property
    def product_state(self) -> frozenset[str]:
        """Of `product_variables`, the product's own estimated variables: without the operations' states."""
        return frozenset(self.product_variables) - {op.state_path for op in self.operations}

    @cached_property
    def variant_by_name(self) -> dict[str, Variant]:
        """The declared variants, or the implicit one of a model that declares none."""
        return {v.name: v for v in (self.variants or (implicit_variant(),))}

    def resource_of(self, path: str) -> Resource | None:
        return self.resource_by_name.get(path.split(".", 1)[0])

    def initial_state(self) -> dict[str, Value]:
        return {path: v.initial for path, v in self.variables.items()}

    def paths_of_kind(self, kind: Kind) -> list[str]:
        return [p for p, v in self.variables.items() if v.kind is kind]

    def var(self, path: str) -> Variable:
        try:
            return self.variables[path]
        except KeyError:
            raise KeyError(f"model {self.name!r} has no variable {path!r}") from None

    # --- validation ----------------------------------------------------------------
    def problems(self) -> list[Problem]:
        problems: list[Problem] = []
        problems += self._duplicates()
        variables = self.variables
        for r in self.resources:
            for v in r.variables:
                if v.resource != r.name:
                    problems.append(Problem(v.path, f"variable of resource {r.name!r} must be named {r.name}.<name>"))
        for v in self._all_variables():
            if v.initial not in v.domain:
                problems.append(
                    Problem(v.path, f"initial value {v.initial!r} is outside its domain {v.domain.describe()}")
                )
        operation_transitions = {t.name for t in self.operation_transitions}
        for t in self.transitions:
            if t.name not in operation_transitions:  # those guards are the operations' pre and goal
                problems += self._check_predicate(t.name, t.guard, variables)
            for outcome in t.outcomes:
                for action in outcome:
                    problems += self._check_action(t, action, variables)
                targets = Counter(a.path for a in outcome)
                for target, count in targets.items():
                    if count > 1:
                        problems.append(Problem(t.name, f"one outcome assigns {target} {count} times",
                                                "; ".join(str(a) for a in outcome)))
            if t.kind is not TransitionKind.EFFECT and len(t.outcomes) != 1:
                problems.append(Problem(t.name, f"a {t.kind.value} transition has exactly one outcome"))
        for a in self.abilities:
            for name, predicate in a.predicates.items():
                problems += self._check_predicate(f"{a.name}.{name}", predicate, variables)
        for op in self.operations:
            problems += self._check_predicate(f"operation {op.name} (pre)", op.pre, variables)
            problems += self._check_predicate(f"operation {op.name} (goal)", op.goal, variables)
        for spec in self.specifications:
            problems += self._check_predicate(f"specification {spec.name}", spec.forbidden, variables)
        if not problems:  # the selection test reads the operations' predicates: only once they are sound
            written = {path for t in self.transitions for path in t.written()}
            problems += [Problem(where, message) for where, message in
                         variant_problems(self.variants, self.product, self.operations, variables, written)]
        # A phase predicate is also its transitions' guard: report each problem once.
        return list(dict.fromkeys(problems))

    def _duplicates(self) -> list[Problem]:
        problems = []
        checks: list[tuple[str, Iterable[str]]] = [
            ("resource", (r.name for r in self.resources)),
            ("variable", (v.path for v in self._all_variables())),
            ("ability", (a.name for a in self.abilities)),
            ("transition", (t.name for t in self.transitions)),
            ("operation", (op.name for op in self.operations)),
            ("specification", (s.name for s in self.specifications)),
        ]
        for what, names in checks:
            for name, count in Counter(names).items():
                if count > 1:
                    problems.append(Problem(name, f"duplicate {what} name (defined {count} times)"))
        return problems

    @staticmethod
    def _check_value(where: str, path: str, value: object, variables: Mapping[str, Variable],
                     expression: str, assigned: bool = False) -> list[Problem]:
        var = variables.get(path)
        if var is None:
            return []  # reported as an unknown variable
        if isinstance(value, Ref):
            other = variables.get(value.path)
            if other is None:
                return []
            if assigned and not set(other.domain.values) <= set(var.domain.values):
                return [Problem(where, f"{path} ({var.domain.describe()}) is assigned {value.path} "
                                       f"({other.domain.describe()}): not every value fits", expression)]
            # bools and ints never mix (True == 1 in a Python set)
            disjoint = not set(other.domain.values) & set(var.domain.values)
            if var.domain.is_bool != other.domain.is_bool or (not assigned and disjoint):
                return [Problem(where, f"{path} ({var.domain.describe()}) compared with {value.path} "
                                       f"({other.domain.describe()}): the domains have no value in common",
                                expression)]
            return []
        if value not in var.domain:
            return [Problem(where, f"value {value!r} is outside the domain of {path} ({var.domain.describe()})",
                            expression)]
        return []

    def _check_predicate(self, where: str, predicate: Predicate, variables: Mapping[str, Variable]) -> list[Problem]:
        problems = []
        text = str(predicate)
        for path in sorted(predicate.paths()):
            if path not in variables:
                problems.append(Problem(where, f"unknown variable {path}", text))
        for path, value in predicate.operands():
            problems += self._check_value(where, path, value, variables, text)
        return problems

    def _check_action(self, t: Transition, action: object, variables: Mapping[str, Variable]) -> list[Problem]:
        from .actions import Assign

        assert isinstance(action, Assign)
        text = str(action)
        problems = []
        for path in sorted(action.paths()):
            if path not in variables:
                problems.append(Problem(t.name, f"unknown variable {path}", text))
        var = variables.get(action.path)
        if var is not None:
            if t.kind is TransitionKind.EFFECT and var.kind is not Kind.MEASURED:
                problems.append(Problem(t.name, f"an effect writes {var.kind.value} variable {var.path}; "
                                                f"effects write measured variables only", text))
            if t.kind is not TransitionKind.EFFECT and var.kind is Kind.MEASURED:
                problems.append(Problem(t.name, f"a {t.kind.value} (control) action writes measured variable "
                                                f"{var.path}; only hubs write measured variables", text))
        problems += self._check_value(t.name, action.path, action.value, variables, text, assigned=True)
        return problems
