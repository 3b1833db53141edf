"""The controller's chain from a station model: supervisor synthesis, the compiled model (the model's guards
and the synthesized ones), the planner, and the control core that runs the engine. Built here once for the
controller process, its planner process, the in-process runner and `hubctl check` / `hubctl plan`."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

from common.config.modes import DEFAULT_EXECUTION, Execution
from common.model import Model
from common.model.compiled import CompiledModel

from .control import ControlCore
from .planner import Budget, Planner
from .synthesis import Supervisor, synthesize


@dataclass(frozen=True)
class ControllerStack:
    model: Model
    supervisor: Supervisor
    compiled: CompiledModel
    planner: Planner

    def control_core(self, clock: Callable[[], float] = time.monotonic, *, budget: Budget | None = None,
                     execution: Execution = DEFAULT_EXECUTION) -> ControlCore:
        """A control core (and its engine, running plans in `execution`) on this stack's compiled model and
        planner."""
        return ControlCore(self.compiled, self.planner, clock, budget=budget, execution=execution)


def build_controller_stack(model: Model, *, prepare: bool = False) -> ControllerStack:
    """Synthesize the supervisor, compile the model with its guards, and set up the planner with the
    forbidden states; `prepare` builds the planner's model tables now rather than at the first request."""
    supervisor = synthesize(model)
    compiled = CompiledModel(model, supervisor.guards)
    planner = Planner(compiled, supervisor.forbidden)
    if prepare:
        planner.prepare()
    return ControllerStack(model, supervisor, compiled, planner)
