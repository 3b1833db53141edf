"""Why an operator's confirmation cannot be taken now: the words the console's refusal and the operator's
page both show, from the operator model's own predicates (common/resources/operator.py).

Pure functions of the values: the controller asks them on its global state (controller/requests.py), the
operator's page on what its hub sees (hubs/drivers/operator_page/)."""

from __future__ import annotations

from collections.abc import Mapping

from common.model import Model, Predicate, Value
from common.model.predicates import And

from .operator import NO_TASK


def unmet(predicate: Predicate, values: Mapping[str, Value]) -> str:
    """The conjuncts of `predicate` that do not hold, in the model's notation."""
    items = predicate.items if isinstance(predicate, And) else (predicate,)
    return " && ".join(str(p) for p in items if not p.eval(values))


def confirmation_effect(operator: str, task: str) -> str:
    """The name of the effect transition by which `operator` confirms `task` (its guard: when it may)."""
    return f"{operator}.{task}.executing.effect"


def instruction_refusal(operator: str, task: Value, done: Value) -> str | None:
    """Why `operator` cannot confirm with instruction `task` standing and the button `done`; None if the
    instruction allows it."""
    if task == NO_TASK:
        return f"{operator} has no instruction to confirm"
    if done:
        return f"{operator} has already confirmed {task}"
    return None


def condition_refusal(operator: str, task: str, guard: Predicate, values: Mapping[str, Value]) -> str | None:
    """Why the model's confirm condition (`guard`, the confirmation effect's) does not let `operator`
    confirm `task` in `values`; None when it holds."""
    if guard.eval(values):
        return None
    return f"{operator} cannot confirm {task} yet: {unmet(guard, values)}"


def confirm_refusal(model: Model, operator: str, values: Mapping[str, Value]) -> str | None:
    """Why `operator` cannot confirm now in `values` (every variable its confirm conditions read), in the
    console's words; None when a press would be taken."""
    task = values[f"{operator}.instr_c"]
    refusal = instruction_refusal(operator, task, values[f"{operator}.done_m"])
    if refusal is not None:
        return refusal
    guard = model.transition_by_name[confirmation_effect(operator, str(task))].guard
    return condition_refusal(operator, str(task), guard, values)
