"""The operator's confirm button as the model sees it: `instr_c` in, `done_m` out, and why a press is refused.

One object per operator resource, shared by every input (the page's button, a smartwatch through the
device endpoint, the GPIO pushbutton), so that the three cannot disagree. A press sets `done_m` only while
an instruction stands and the model's confirm condition holds (the confirmation effect's guard, on what the
hub sees of the station); the button is released as the model's `release_button` effect expects: once the
instruction is withdrawn (`instr_c == none`), `done_m` goes false again."""

from __future__ import annotations

from collections.abc import Callable, Mapping

from common.model import Model, Value
from common.resources.operator import NO_TASK
from common.resources.operator_confirm import confirm_refusal, confirmation_effect


def _as_sequence(value: object) -> tuple[object, ...]:
    """The operator resource's `tasks` parameter (common/resources/operator.py stores a tuple)."""
    if not isinstance(value, (tuple, list)):
        raise TypeError(f"the operator's 'tasks' parameter is {value!r}, not a list of task names")
    return tuple(value)


class OperatorButton:
    def __init__(self, model: Model, resource: str, on_change: Callable[[], None] = lambda: None) -> None:
        self.model = model
        self.resource = resource
        self.on_change = on_change  # told after every change of what the page shows
        spec = model.resource_by_name[resource]
        self.tasks: tuple[str, ...] = tuple(str(task) for task in _as_sequence(spec.parameters.get("tasks", ())))
        self.instr_path, self.done_path = f"{resource}.instr_c", f"{resource}.done_m"
        guards = [model.transition_by_name[confirmation_effect(resource, task)].guard for task in self.tasks]
        own = {self.instr_path, self.done_path}
        # The other variables the confirm conditions read: the hub subscribes to them for this driver.
        self.condition_paths = tuple(sorted({p for g in guards for p in g.paths()} - own))
        self.values: dict[str, Value] = {p: model.var(p).initial for p in (*self.condition_paths, *own)}

    @property
    def instruction(self) -> str:
        return str(self.values[self.instr_path])

    @property
    def done(self) -> bool:
        return bool(self.values[self.done_path])

    def refusal(self) -> str | None:
        """Why a press would be refused now (the console's words), None when it would be taken."""
        return confirm_refusal(self.model, self.resource, self.values)

    def press(self) -> str | None:
        """A press of the button: None when it confirmed the instruction, else why not (nothing changed)."""
        refusal = self.refusal()
        if refusal is None:
            self.values[self.done_path] = True
            self.on_change()
        return refusal

    def command(self, instruction: Value) -> None:
        """The controller's `instr_c`. A withdrawn instruction releases the button."""
        changed = self.values[self.instr_path] != instruction
        self.values[self.instr_path] = instruction
        if instruction == NO_TASK and self.done:
            self.values[self.done_path] = False
            changed = True
        if changed:
            self.on_change()

    def observe(self, values: Mapping[str, Value]) -> None:
        changed = False
        for path in self.condition_paths:
            if path in values and self.values[path] != values[path]:
                self.values[path] = values[path]
                changed = True
        if changed:
            self.on_change()
