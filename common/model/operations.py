"""Planning operations and forbidden-state specifications."""

from __future__ import annotations

import enum
from dataclasses import dataclass

from .actions import Assign
from .predicates import In, Predicate, all_of
from .transitions import ActionsLike, Transition, _actions, automatic, deliberate
from .variables import Domain, Variable, estimated


class OperationState(enum.StrEnum):
    """The value of an operation's state variable `op.NAME`, spelt as the model, the controller's status and
    its database spell it."""

    INITIAL = "initial"
    EXECUTING = "executing"  # started: its goal is planned for
    FINISHED = "finished"  # its goal held
    ERROR = "error"  # started, but its goal has no plan (the controller tries again)


# Plain strings in the model and the state tuples: the compiled model writes values into generated code.
OPERATION_STATES = Domain.enum(*(s.value for s in OperationState))
RUNNING = (OperationState.EXECUTING.value, OperationState.ERROR.value)  # started and not finished


def operation_running(name: str) -> Predicate:
    """Operation `name` has started and not finished (executing, or in error)."""
    return In(f"op.{name}", RUNNING)


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
        return estimated(self.state_path, OPERATION_STATES, OperationState.INITIAL.value, self.description)

    def start_transition(self) -> Transition:
        state = self.state_path
        return deliberate(f"{state}.start", all_of(f"{state} == {OperationState.INITIAL}", self.pre),
                          (f"{state} := {OperationState.EXECUTING}", *self.on_start))

    def finish_transition(self) -> Transition:
        state = self.state_path
        return automatic(f"{state}.finish", all_of(operation_running(self.name), self.goal),
                         (f"{state} := {OperationState.FINISHED}", *self.on_finish))


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
