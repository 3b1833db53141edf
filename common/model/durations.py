"""How long effects take: a duration interval per resource, the one source every reader of time uses.

Every effect takes between `min_s` and `max_s` seconds from the moment its guard holds (DESIGN.md
§4, "Time is part of the model"). An effect belongs to the resource whose measured variables it
writes, so a duration is kept per resource, chosen in this order:

1. `delay` of the device in hubs.toml (a number, or a `[min, max]` pair: `common/config/hubs_toml.py`);
2. the resource's own declaration in its model (`Resource.duration`; a station's own device type
   says it there; `parameters["emulated_delay"] = seconds` is the older spelling of the same);
3. the declaration of its standard device type (`DURATION` in each `common/resources/*.py`, by type
   name in `common.resources.TYPE_DURATIONS`);
4. `FALLBACK`, which `hubctl check` names: a type that declares nothing runs on a guess.

A type may also say that some of its abilities take their own time whatever the device's duration
(`Resource.ability_durations`: the operator's task takes `delay`, releasing the watch's button does not);
those effects take that, over all four. `DurationTable.keyed()` gives both as one mapping, by resource and
by effect transition name, for the readers that take a mapping (the timed check), and `duration_in` reads it.

`common.resources.durations_of(model, configured)` builds a station's table with the standard types'
declarations; the emulator, `hubctl plan` and `hubctl check` read that table, and the planner, the
scheduler and the cycle bound are to read the same one. Deliberate and automatic transitions are the
controller's own and take no time.
"""

from __future__ import annotations

import math
import random
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING

from .transitions import Transition, TransitionKind

if TYPE_CHECKING:
    from .model import Model
    from .resource import Resource


@dataclass(frozen=True)
class Duration:
    """An interval of seconds, `min_s <= max_s`, both finite and not negative."""

    min_s: float
    max_s: float

    def __post_init__(self) -> None:
        for bound in (self.min_s, self.max_s):
            if isinstance(bound, bool) or not isinstance(bound, int | float) or not math.isfinite(bound) or bound < 0:
                raise ValueError(f"a duration is seconds, finite and not negative: got {bound!r}")
        if self.min_s > self.max_s:
            raise ValueError(f"a duration's min ({self.min_s:g} s) is above its max ({self.max_s:g} s)")

    @classmethod
    def fixed(cls, seconds: float) -> Duration:
        return cls(seconds, seconds)

    @property
    def is_fixed(self) -> bool:
        return self.min_s == self.max_s

    def scaled(self, speed: float) -> Duration:
        """The interval at `speed` (2 = twice as fast), as the emulator's `--speed` runs it."""
        return Duration(self.min_s / speed, self.max_s / speed)

    def pick(self, rng: random.Random) -> float:
        """A time within the interval. A fixed duration draws nothing from `rng`, so runs recorded
        with fixed delays replay the same random choices of outcomes."""
        if self.is_fixed:
            return self.min_s
        return rng.uniform(self.min_s, self.max_s)

    def __str__(self) -> str:
        if self.is_fixed:
            return f"{self.min_s:g} s"
        return f"{self.min_s:g}-{self.max_s:g} s"


INSTANT = Duration.fixed(0.0)
# What an effect of a device type that declares no duration takes: a guess, said by `hubctl check`.
FALLBACK = Duration.fixed(0.2)


class DurationSource(Enum):
    """Where a resource's duration was declared (highest precedence first)."""

    CONFIG = "hubs.toml delay"
    RESOURCE = "the resource's model"
    DEVICE_TYPE = "its device type"
    FALLBACK = "fallback: its type declares none"


@dataclass(frozen=True)
class ResourceDuration:
    resource: str
    device_type: str
    duration: Duration
    source: DurationSource


def declared_duration(resource: Resource) -> Duration | None:
    """What the resource's model itself declares, if anything."""
    if resource.duration is not None:
        return resource.duration
    legacy = resource.parameters.get("emulated_delay")
    if isinstance(legacy, int | float) and not isinstance(legacy, bool) and legacy >= 0:
        return Duration.fixed(float(legacy))
    return None


class DurationTable:
    """The duration of every resource's effects in one station."""

    def __init__(self, entries: Iterable[ResourceDuration], effects: Mapping[str, Duration] | None = None) -> None:
        """`effects`: effect transition name -> its ability's own duration (`Resource.ability_durations`)."""
        self._entries: dict[str, ResourceDuration] = {e.resource: e for e in entries}
        self._effects: dict[str, Duration] = dict(effects or {})

    @classmethod
    def build(cls, model: Model, *, type_defaults: Mapping[str, Duration],
              configured: Mapping[str, Duration] | None = None) -> DurationTable:
        """`type_defaults`: device type -> its declared duration; `configured`: resource -> hubs.toml's delay."""
        configured = configured or {}
        unknown = sorted(set(configured) - set(model.resource_by_name))
        if unknown:
            raise KeyError(f"model {model.name!r} has no resource {', '.join(unknown)} (a configured delay)")
        entries = []
        for resource in model.resources:
            own = declared_duration(resource)
            if resource.name in configured:
                duration, source = configured[resource.name], DurationSource.CONFIG
            elif own is not None:
                duration, source = own, DurationSource.RESOURCE
            elif resource.device_type in type_defaults:
                duration, source = type_defaults[resource.device_type], DurationSource.DEVICE_TYPE
            else:
                duration, source = FALLBACK, DurationSource.FALLBACK
            entries.append(ResourceDuration(resource.name, resource.device_type, duration, source))
        return cls(entries, _ability_effects(model))

    @property
    def entries(self) -> tuple[ResourceDuration, ...]:
        return tuple(self._entries.values())

    def entry(self, resource: str) -> ResourceDuration:
        try:
            return self._entries[resource]
        except KeyError:
            raise KeyError(f"no duration for resource {resource!r}: it is not in the station model") from None

    def of_resource(self, resource: str) -> Duration:
        return self.entry(resource).duration

    @property
    def own_effects(self) -> dict[str, Duration]:
        """The effects whose ability declares its own duration, by transition name."""
        return dict(self._effects)

    def of_transition(self, transition: Transition) -> Duration:
        """An effect takes its ability's own duration, else its resource's; the controller's own transitions
        take no time."""
        if transition.kind is not TransitionKind.EFFECT:
            return INSTANT
        own = self._effects.get(transition.name)
        return own if own is not None else self.of_resource(effect_owner(transition))

    def keyed(self) -> dict[str, Duration]:
        """Each resource's duration by its name and each effect with its ability's own by the effect's name
        (read with `duration_in`)."""
        return {**{e.resource: e.duration for e in self._entries.values()}, **self._effects}


def duration_in(durations: Mapping[str, Duration], effect: str, owner: str) -> Duration:
    """An effect's duration in a `DurationTable.keyed()` mapping: its own, else its resource's."""
    own = durations.get(effect)
    return own if own is not None else durations[owner]


def _ability_effects(model: Model) -> dict[str, Duration]:
    effects: dict[str, Duration] = {}
    for resource in model.resources:
        declared = dict(resource.ability_durations)
        for ability in resource.abilities:
            short = ability.name.split(".", 1)[1] if "." in ability.name else ability.name
            own = declared.pop(short, None)
            if own is None:
                continue
            for t in ability.transitions:
                if t.kind is TransitionKind.EFFECT:
                    effects[t.name] = own
        if declared:
            raise KeyError(f"resource {resource.name!r} declares durations of abilities it does not have: "
                           f"{', '.join(sorted(declared))}")
    return effects


def writer_owner(transition: Transition) -> str | None:
    """The resource whose variables a transition writes (the first in name order; None: it writes none)."""
    written = sorted(transition.written())
    return written[0].split(".", 1)[0] if written else None


def effect_owner(transition: Transition) -> str:
    """The resource whose device makes an effect happen: the one whose measured variables it writes."""
    owner = writer_owner(transition)
    if owner is None:
        raise ValueError(f"effect {transition.name} writes nothing")
    return owner


def effect_delays(model: Model, configured: Mapping[str, Duration | float] | None = None) -> dict[str, float]:
    """The longest each effect of the model takes, by transition name: what the engine bounds a held
    step by (controller/engine.py). `configured`: resource -> hubs.toml's delay."""
    return {name: duration.max_s for name, duration in _effect_durations(model, configured).items()}


def effect_shortest(model: Model, configured: Mapping[str, Duration | float] | None = None) -> dict[str, float]:
    """The shortest each effect of the model takes, by transition name: what a lower bound on a run counts
    (controller/cycle.py: no schedule is shorter only if no effect is taken faster than it can be)."""
    return {name: duration.min_s for name, duration in _effect_durations(model, configured).items()}


def _effect_durations(model: Model, configured: Mapping[str, Duration | float] | None) -> dict[str, Duration]:
    # The standard types' declarations live in common.resources, a package built on this one.
    from common.resources import durations_of

    table = durations_of(model, {r: as_duration(d) for r, d in (configured or {}).items()})
    return {t.name: table.of_transition(t) for t in model.ability_transitions
            if t.kind is TransitionKind.EFFECT and t.written()}


def as_duration(value: Duration | float) -> Duration:
    """A duration as given: an interval, or a number of seconds (fixed)."""
    return value if isinstance(value, Duration) else Duration.fixed(value)
