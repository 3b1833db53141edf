"""How long a device's effects take: the one table the emulator and the controller's engine read.

Seconds an effect takes at speed 1, by device type: the operator is slower than the robot. A
device type of a station's own says its delay in its resource model (`parameters["emulated_delay"]`),
else it gets FALLBACK_DELAY; `delay` per device in hubs.toml overrides both (`overrides`, by resource).
An effect belongs to the resource whose measured variable it writes.
"""

from __future__ import annotations

from collections.abc import Mapping

from .model import Model
from .resource import Resource
from .transitions import Transition, TransitionKind

DEFAULT_DELAYS: dict[str, float] = {
    "nutrunner": 0.12,
    "ur": 0.15,
    "rsp": 0.15,
    "dock": 0.1,
    "lift": 0.3,
    "mir": 0.8,
    "agv": 0.8,
    "rfid": 0.4,
    "camera": 0.1,
    "operator": 0.5,
}
FALLBACK_DELAY = 0.2


def resource_delay(resource: Resource, overrides: Mapping[str, float] | None = None) -> float:
    """Seconds each effect of `resource` takes at speed 1."""
    if overrides and resource.name in overrides:
        return overrides[resource.name]
    own = resource.parameters.get("emulated_delay")
    if isinstance(own, int | float) and not isinstance(own, bool) and own >= 0:
        return float(own)
    return DEFAULT_DELAYS.get(resource.device_type, FALLBACK_DELAY)


def effect_owner(t: Transition) -> str:
    return next(iter(t.written())).split(".", 1)[0]


def effect_delays(model: Model, overrides: Mapping[str, float] | None = None) -> dict[str, float]:
    """Seconds each effect transition of the model takes at speed 1, by transition name."""
    return {t.name: resource_delay(model.resource_by_name[effect_owner(t)], overrides)
            for t in model.ability_transitions
            if t.kind is TransitionKind.EFFECT and t.written() and effect_owner(t) in model.resource_by_name}
