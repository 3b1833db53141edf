"""Actions: `var := value` and `var := other.var`."""

from __future__ import annotations

from collections.abc import Mapping, MutableMapping
from dataclasses import dataclass

from .predicates import Operand, Ref, format_value, operand_value
from .variables import Value


@dataclass(frozen=True)
class Assign:
    path: str
    value: Operand

    def apply(self, source: Mapping[str, Value], target: MutableMapping[str, Value]) -> None:
        """Write into `target`, reading right-hand variables from `source` (the state before)."""
        target[self.path] = operand_value(self.value, source)

    def paths(self) -> set[str]:
        return {self.path} | ({self.value.path} if isinstance(self.value, Ref) else set())

    def __str__(self) -> str:
        return f"{self.path} := {format_value(self.value)}"


def as_action(item: object) -> Assign:
    if isinstance(item, Assign):
        return item
    if isinstance(item, str):
        from .parser import parse_action

        return parse_action(item)
    raise TypeError(f"not an action: {item!r}")


def apply_all(actions: tuple[Assign, ...], state: Mapping[str, Value]) -> dict[str, Value]:
    """The state after the actions, all reading the state before (simultaneous assignment)."""
    after = dict(state)
    for action in actions:
        action.apply(state, after)
    return after
