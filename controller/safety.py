"""The model's forbidden specifications checked on the station as it is, not only as the model predicts it.

The supervisor (controller/synthesis.py) keeps every deliberate transition out of the states from which
the model's uncontrollable transitions reach a forbidden state. A device that does not behave as
modelled, or an operator's force, can still bring the station into one. So each tick the controller
evaluates every specification on its state (the hubs' measurements, its estimates and the commands it
sends): while one holds, it fires no deliberate transition (no plan step, no operation start) and does
not plan; the specification and the values that make it hold are reported once, and again when it
clears. A console force that would make a specification hold is refused unless overridden.

A specification that reads a command variable whose value the controller does not know (a resource held
after a restart, `controller/command_hold.py`) is not evaluated: its verdict would rest on a guess.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from common.model import Predicate, Value
from common.model.compiled import CompiledModel, State
from common.model.predicates import And, Or, format_value
from common.wire.ctl import ForbiddenState, ForbiddenStateCleared

log = logging.getLogger("statehub.controller.safety")


@dataclass(frozen=True)
class Violation:
    """A specification whose forbidden state holds, with the variables that make it hold."""

    specification: str
    values: dict[str, Value]

    def describe(self) -> str:
        values = ", ".join(f"{p} = {format_value(v)}" for p, v in self.values.items())
        return f"{self.specification} ({values})"


@dataclass(frozen=True)
class _Spec:
    name: str
    forbidden: Predicate
    holds: Callable[[State], bool]
    reads: frozenset[int]


def witness(predicate: Predicate, values: Mapping[str, Value]) -> dict[str, Value]:
    """The variables (with their values) of the parts of a holding predicate that make it hold: for a
    disjunction only the first operand that holds, so a report names one way it holds, not every variable."""
    if isinstance(predicate, Or):
        holding = next((p for p in predicate.items if p.eval(values)), None)
        if holding is not None:
            return witness(holding, values)
    if isinstance(predicate, And):
        found: dict[str, Value] = {}
        for p in predicate.items:
            found.update(witness(p, values))
        return found
    return {path: values[path] for path in sorted(predicate.paths())}


class SafetyMonitor:
    def __init__(self, compiled: CompiledModel) -> None:
        self.compiled = compiled
        self.specs = tuple(
            _Spec(s.name, s.forbidden, compiled.predicate(s.forbidden),
                  frozenset(compiled.index[p] for p in s.forbidden.paths()))
            for s in compiled.model.specifications)
        self.holding: dict[str, Violation] = {}

    @property
    def stopped(self) -> bool:
        """A forbidden state holds: deliberate transitions wait."""
        return bool(self.holding)

    def violations(self, state: State, unknown: frozenset[int] = frozenset(),
                   reading: frozenset[int] | None = None) -> list[Violation]:
        """The specifications that hold in `state`, leaving out those reading an `unknown` variable (and, if
        `reading` is given, those reading none of these variables)."""
        found = []
        for spec in self.specs:
            if spec.reads & unknown or (reading is not None and not spec.reads & reading):
                continue
            if spec.holds(state):
                found.append(Violation(spec.name, witness(spec.forbidden, self.compiled.unpack(state))))
        return found

    def check(self, state: State,
              unknown: frozenset[int] = frozenset()) -> list[ForbiddenState | ForbiddenStateCleared]:
        """Evaluate every specification now; the events of those that began or stopped holding."""
        now = {v.specification: v for v in self.violations(state, unknown)}
        events: list[ForbiddenState | ForbiddenStateCleared] = []
        for name, violation in now.items():
            if name not in self.holding:
                log.error("forbidden state: %s holds: deliberate transitions stopped", violation.describe())
                events.append(ForbiddenState(name, dict(violation.values)))
        for name in self.holding:
            if name not in now:
                log.warning("forbidden state cleared: %s no longer holds", name)
                events.append(ForbiddenStateCleared(name))
        self.holding = now
        return events

    def made_to_hold(self, state: State, values: Mapping[str, Value],
                     unknown: frozenset[int] = frozenset()) -> list[Violation]:
        """The specifications that setting `values` in `state` would make hold (those holding already
        excepted: a force that does not worsen the state is the operator's way out of it)."""
        before = {v.specification for v in self.violations(state, unknown)}
        after = self.compiled.with_values(state, values)
        return [v for v in self.violations(after, unknown) if v.specification not in before]
