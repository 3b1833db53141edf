"""Abilities: the generalized operations of one resource, as named predicates and their transitions.

The standard predicate names follow the paper: enabled, starting, executing,
finished, resetting. Each `Phase` names the predicate and the transitions that
leave it, so a model reads like the paper's tables:

    nutrunner_tighten = ability("nr.tighten",
        enabled=Phase("!nr.run_c && !nr.run_m", deliberate="nr.run_c := true"),
        starting=Phase("nr.run_c && !nr.run_m", effects=["nr.run_m := true"]),
        ...)

Abilities are templates: a function returning `ability(...)` with a parameter is
one ability per bolt or per pose, instantiated in a loop.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

from .actions import Assign
from .predicates import Predicate, all_of, as_predicate
from .transitions import ActionsLike, Transition, automatic, deliberate, effect

STANDARD_PHASES = ("enabled", "starting", "executing", "finished", "resetting")


@dataclass(frozen=True)
class Phase:
    """A named predicate and what leaves it: a deliberate action, an automatic action, device effects.

    `effects` lists alternative outcomes, each an action or a list of actions.
    `guard` is an extra condition on the transitions only (not part of the predicate).
    """

    predicate: object
    deliberate: ActionsLike = ()
    automatic: ActionsLike = ()
    effects: Iterable[ActionsLike] | Assign | str = ()
    guard: object = True


@dataclass(frozen=True)
class Ability:
    name: str
    predicates: dict[str, Predicate] = field(hash=False)
    transitions: tuple[Transition, ...]

    @property
    def resource(self) -> str:
        return self.name.split(".", 1)[0]

    def transition(self, name: str) -> Transition:
        for t in self.transitions:
            if t.name == name or t.name == f"{self.name}.{name}":
                return t
        raise KeyError(f"ability {self.name} has no transition {name!r}")


def ability(name: str, *, extra: Iterable[Transition] = (), **phases: Phase | object) -> Ability:
    """Build an ability from phases (`enabled=Phase(...)`); a bare predicate names a phase with no transitions."""
    predicates: dict[str, Predicate] = {}
    transitions: list[Transition] = []
    for phase_name, phase in phases.items():
        if not isinstance(phase, Phase):
            phase = Phase(phase)
        predicate = as_predicate(phase.predicate)
        predicates[phase_name] = predicate
        guard = all_of(predicate, phase.guard)
        prefix = f"{name}.{phase_name}"
        if phase.deliberate:
            transitions.append(deliberate(prefix, guard, phase.deliberate))
        if phase.automatic:
            transitions.append(automatic(f"{prefix}.auto" if phase.deliberate else prefix, guard, phase.automatic))
        # A bare action is one outcome, not a sequence of characters.
        effects = phase.effects
        outcomes = [effects] if isinstance(effects, str | Assign) else list(effects)
        if outcomes:
            transitions.append(effect(f"{prefix}.effect", guard, *outcomes))
    transitions.extend(extra)
    return Ability(name, predicates, tuple(transitions))


def tracking(name: str, guard: object, actions: ActionsLike) -> Ability:
    """A tracking ability: one automatic transition that updates estimated state from measurements."""
    return Ability(name, {"enabled": all_of(guard)}, (automatic(name, guard, actions),))
