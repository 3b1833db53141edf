"""Planning operations and forbidden-state specifications."""

from __future__ import annotations

from dataclasses import dataclass

from .actions import Assign
from .predicates import Predicate, all_of
from .transitions import ActionsLike, Transition, _actions, automatic, deliberate
from .variables import Domain, Variable, estimated

OPERATION_STATES = Domain.enum("initial", "executing", "finished", "error")


@dataclass(frozen=True)
class Operation:
    """Precondition, goal, optional actions on start and finish, and its own state variable `op.NAME`."""

    name: str
    pre: Predicate
    goal: Predicate
    on_start: tuple[Assign, ...] = ()
    on_finish: tuple[Assign, ...] = ()
    description: str = ""

    @property
    def state_path(self) -> str:
        return f"op.{self.name}"

    def state_variable(self) -> Variable:
        return estimated(self.state_path, OPERATION_STATES, "initial", self.description)

    def start_transition(self) -> Transition:
        state = self.state_path
        return deliberate(f"{state}.start", all_of(f"{state} == initial", self.pre),
                          (f"{state} := executing", *self.on_start))

    def finish_transition(self) -> Transition:
        state = self.state_path
        return automatic(f"{state}.finish", all_of(f"{state} in {{executing, error}}", self.goal),
                         (f"{state} := finished", *self.on_finish))


def operation(name: str, pre: object, goal: object, on_start: ActionsLike = (), on_finish: ActionsLike = (),
              description: str = "") -> Operation:
    return Operation(name, all_of(pre), all_of(goal), _actions(on_start), _actions(on_finish), description)


@dataclass(frozen=True)
class Specification:
    """A forbidden-state predicate: no reachable state may satisfy it."""

    name: str
    forbidden: Predicate
    description: str = ""


def forbid(name: str, forbidden: object, description: str = "") -> Specification:
    return Specification(name, all_of(forbidden), description)
