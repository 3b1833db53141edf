"""Resources: a device's measured, command and estimated variables and its abilities."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

from .abilities import Ability
from .durations import Duration
from .variables import Kind, Variable


@dataclass(frozen=True)
class Resource:
    name: str
    variables: tuple[Variable, ...]
    abilities: tuple[Ability, ...] = ()
    device_type: str = ""
    # Random command sequences may move it (a robot): model-based tests refuse it by default.
    unsafe_for_random_commands: bool = False
    parameters: dict[str, object] = field(default_factory=dict, hash=False, compare=False)
    # How long its effects take, when its model says so (a station's own device type); else its
    # standard type's, or hubs.toml's `delay` (common/model/durations.py). Not in repr: recordings
    # identify a model by its repr's hash, which durations (like hubs.toml's delay) never entered.
    duration: Duration | None = field(default=None, compare=False, repr=False)
    # Abilities whose effects take their own time whatever the device's duration, by the ability's short
    # name (the operator's button release is quick however long a task takes): declared by the type.
    ability_durations: dict[str, Duration] = field(default_factory=dict, hash=False, compare=False, repr=False)

    def of_kind(self, kind: Kind) -> tuple[Variable, ...]:
        return tuple(v for v in self.variables if v.kind is kind)

    @property
    def measured(self) -> tuple[Variable, ...]:
        return self.of_kind(Kind.MEASURED)

    @property
    def commands(self) -> tuple[Variable, ...]:
        return self.of_kind(Kind.COMMAND)

    @property
    def estimated(self) -> tuple[Variable, ...]:
        return self.of_kind(Kind.ESTIMATED)

    def var(self, name: str) -> Variable:
        path = name if "." in name else f"{self.name}.{name}"
        for v in self.variables:
            if v.path == path:
                return v
        raise KeyError(f"resource {self.name} has no variable {name!r}")

    def __getattr__(self, name: str) -> Variable:
        # `nr.run_c` reads like the paper when building predicates with operators.
        if name.startswith("_"):
            raise AttributeError(name)
        try:
            return self.var(name)
        except KeyError as exc:
            raise AttributeError(str(exc)) from None

    def with_abilities(self, extra: Iterable[Ability]) -> Resource:
        return Resource(self.name, self.variables, (*self.abilities, *extra), self.device_type,
                        self.unsafe_for_random_commands, self.parameters, self.duration, self.ability_durations)
