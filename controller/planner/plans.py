"""What a planner returns: a plan (steps and the states they pass through) or the reason there is none."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

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
    guard: str  # CompiledModel.guard_of, printed: the synthesized guards are part of it
    actions: str = ""  # the chosen outcome's actions, printed

    def __str__(self) -> str:
        return f"{self.transition} [{self.kind.value}] when {self.guard} -> {self.actions}"


@dataclass(frozen=True)
class PlanStats:
    method: str  # "astar", "bfs", "trivial"
    seconds: float = 0.0  # wall time of the whole call, heuristic build included
    expanded: int = 0  # states whose successors were generated
    generated: int = 0  # successor states produced
    heuristic_seconds: float = 0.0  # of `seconds`, building abstractions and distance tables (0 when cached)


@dataclass(frozen=True)
class Plan:
    steps: tuple[PlanStep, ...]
    states: tuple[State, ...]  # len(steps) + 1; states[0] is the start, states[-1] satisfies the goals
    goals: tuple[str, ...]
    stats: PlanStats = field(default_factory=lambda: PlanStats("none"), compare=False)

    def explain(self, compiled: CompiledModel) -> str:
        """Numbered steps with guards and the variables each step changed, one per line."""
        lines = [f"plan for {', '.join(self.goals) or '(no goals)'}: {len(self.steps)} step(s)"]
        transitions = zip(self.steps, self.states, self.states[1:], strict=False)
        for number, (step, before, after) in enumerate(transitions, start=1):
            changed = ", ".join(
                f"{compiled.paths[i]}={after[i]!r}" for i in range(len(after)) if after[i] != before[i]
            )
            lines.append(f"{number:>4}. {step}" + (f"   => {changed}" if changed else ""))
        return "\n".join(lines)


@dataclass(frozen=True)
class NoPlan:
    reason: str
    unreachable: tuple[str, ...] = ()  # a smallest subset of the goal names that cannot be reached together
    stats: PlanStats = field(default_factory=lambda: PlanStats("none"), compare=False)

    def __str__(self) -> str:
        which = f" (unreachable: {', '.join(self.unreachable)})" if self.unreachable else ""
        return f"no plan: {self.reason}{which}"
