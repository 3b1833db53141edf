"""Transitions: a guard and actions, of one of three kinds."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from enum import Enum

from .actions import Assign, as_action
from .predicates import Predicate, all_of


class TransitionKind(Enum):
    DELIBERATE = "deliberate"  # fires only when the plan asks for it
    AUTOMATIC = "automatic"  # fires whenever its guard holds
    EFFECT = "effect"  # what the device does by itself; never applied by the controller


@dataclass(frozen=True)
class Transition:
    """`guard -> actions`. An effect may have several alternative outcomes; the others exactly one."""

    name: str
    kind: TransitionKind
    guard: Predicate
    outcomes: tuple[tuple[Assign, ...], ...]

    @property
    def actions(self) -> tuple[Assign, ...]:
        return self.outcomes[0]

    @property
    def controllable(self) -> bool:
        return self.kind is not TransitionKind.EFFECT

    def written(self) -> set[str]:
        return {a.path for outcome in self.outcomes for a in outcome}

    def read(self) -> set[str]:
        paths = set(self.guard.paths())
        for outcome in self.outcomes:
            for action in outcome:
                paths |= action.paths() - {action.path}
        return paths

    def __str__(self) -> str:
        body = " | ".join("; ".join(str(a) for a in outcome) for outcome in self.outcomes)
        return f"{self.name} [{self.kind.value}]: {self.guard} -> {body}"


ActionsLike = Iterable[Assign | str] | Assign | str


def _actions(items: ActionsLike) -> tuple[Assign, ...]:
    if isinstance(items, str | Assign):
        items = [items]
    return tuple(as_action(a) for a in items)


def deliberate(name: str, guard: object, actions: ActionsLike) -> Transition:
    return Transition(name, TransitionKind.DELIBERATE, all_of(guard), (_actions(actions),))


def automatic(name: str, guard: object, actions: ActionsLike) -> Transition:
    return Transition(name, TransitionKind.AUTOMATIC, all_of(guard), (_actions(actions),))


def effect(name: str, guard: object, *outcomes: ActionsLike) -> Transition:
    """An effect; give several action lists for alternative outcomes (`tqr_m := true` or `fail_m := true`)."""
    if not outcomes:
        raise ValueError(f"effect {name} has no outcome")
    return Transition(name, TransitionKind.EFFECT, all_of(guard), tuple(_actions(o) for o in outcomes))
