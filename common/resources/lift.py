"""The lifting system: sent down or up; measured down, between or up.

One ability per target (`lift.move_up`, `lift.move_down`): command the target, the
lift leaves (`pos_m := between`) and arrives (`pos_m := target`).
"""

from __future__ import annotations

from common.model import Domain, Duration, Resource, command, measured

from ._motion import goto_abilities

# How long one effect of the type takes, unless a device's `delay` in hubs.toml says otherwise.
# Leaving a position, or arriving at the next one.
DURATION = Duration.fixed(0.3)

BETWEEN = "between"


def lift(name: str = "lift") -> Resource:
    ref_c = command(f"{name}.ref_c", Domain.enum("down", "up"), "down", "where the lift is sent")
    pos_m = measured(f"{name}.pos_m", Domain.enum("down", BETWEEN, "up"), "down", "where the lift is")
    abilities = goto_abilities(f"{name}.move", ref_c, pos_m, {"up": "up", "down": "down"}, BETWEEN)
    return Resource(name, (ref_c, pos_m), abilities, device_type="lift")
