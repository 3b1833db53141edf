"""What a planner returns: a plan (steps and the states they pass through) or the reason there is none."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from common.config.modes import Execution
from common.model import TransitionKind
from common.model.compiled import State

if TYPE_CHECKING:
    from common.model.compiled import CompiledModel


@dataclass(frozen=True)
class PlanStep:
    """One step: a transition (one outcome of an effect), printed with its full guard and the chosen actions."""

    transition: str
    kind: TransitionKind
    outcome: int
    guard: str  # the model's own guard, printed
    actions: str = ""  # the chosen outcome's actions, printed
    held_by: tuple[str, ...] = ()  # specifications whose synthesized guard this step also needs
    synthesized: str = ""  # that synthesized guard, printed (long: shown only on request)

    def __str__(self) -> str:
        return self.describe()

    def describe(self, synthesized: bool = False) -> str:
        guard = self.guard
        if self.held_by:
            guard += (f" && [{self.synthesized}]" if synthesized
                      else f"  (and the supervisor's guard for: {', '.join(self.held_by)})")
        return f"{self.transition} [{self.kind.value}] when {guard} -> {self.actions}"


def moves_of(compiled: CompiledModel, steps: Iterable[PlanStep]) -> list[tuple[int, int]]:
    """Steps back as (transition number, outcome) moves, what the searches and `plan_from_moves` use."""
    return [(compiled.by_name[step.transition].number, step.outcome) for step in steps]


@dataclass(frozen=True)
class PlanStats:
    method: str  # the member that found it: "greedy", "astar", "symbolic", "bfs", "trivial", "revalidated",
    # "reused" (the rest of the plan last found for the same goals, `reuse.py`)
    seconds: float = 0.0  # wall time of the whole call until this answer, heuristic build included
    expanded: int = 0  # states whose successors were generated (all members so far)
    generated: int = 0  # successor states produced
    heuristic_seconds: float = 0.0  # of `seconds`, building abstractions and distance tables (0 when cached)
    minimal: bool = False  # shown to be a shortest plan (A* or symbolic search, or A* exhausted below it)
    first_seconds: float = 0.0  # when the portfolio had its first valid plan
    first_length: int = -1  # that first plan's length (-1: this is the first)


@dataclass(frozen=True)
class Plan:
    steps: tuple[PlanStep, ...]
    states: tuple[State, ...]  # len(steps) + 1; states[0] is the start, states[-1] satisfies the goals
    goals: tuple[str, ...]
    stats: PlanStats = field(default_factory=lambda: PlanStats("none"), compare=False)
    # How the engine dispatches it, when the timed check (controller/timed_check.py) chose; None: the engine's own.
    execution: Execution | None = field(default=None, compare=False)

    def explain(self, compiled: CompiledModel, synthesized: bool = False) -> str:
        """Numbered steps with guards and the variables each step changed, one per line; the synthesized
        guards are named by their specifications unless `synthesized` asks for them in full."""
        lines = [f"plan for {', '.join(self.goals) or '(no goals)'}: {len(self.steps)} step(s)"]
        transitions = zip(self.steps, self.states, self.states[1:], strict=False)
        for number, (step, before, after) in enumerate(transitions, start=1):
            changed = ", ".join(
                f"{compiled.paths[i]}={after[i]!r}" for i in range(len(after)) if after[i] != before[i]
            )
            lines.append(f"{number:>4}. {step.describe(synthesized)}" + (f"   => {changed}" if changed else ""))
        return "\n".join(lines)


@dataclass(frozen=True)
class NoPlan:
    reason: str
    unreachable: tuple[str, ...] = ()  # a smallest subset of the goal names that cannot be reached together
    stats: PlanStats = field(default_factory=lambda: PlanStats("none"), compare=False)
    proven: bool = False  # shown unreachable; False: not found within the budget (worth a retry)

    def __str__(self) -> str:
        which = f" (unreachable: {', '.join(self.unreachable)})" if self.unreachable else ""
        return f"no plan: {self.reason}{which}"
