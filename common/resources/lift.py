"""The lifting system: sent down or up; measured down, between or up.

One ability per target (`lift.move_up`, `lift.move_down`): command the target, the
lift leaves (`pos_m := between`) and arrives (`pos_m := target`).
"""

from __future__ import annotations

from common.model import Domain, Resource, command, measured

from ._motion import goto_abilities

BETWEEN = "between"


def lift(name: str = "lift") -> Resource:
    ref_c = command(f"{name}.ref_c", Domain.enum("down", "up"), "down", "where the lift is sent")
    pos_m = measured(f"{name}.pos_m", Domain.enum("down", BETWEEN, "up"), "down", "where the lift is")
    abilities = goto_abilities(f"{name}.move", ref_c, pos_m, {"up": "up", "down": "down"}, BETWEEN)
    return Resource(name, (ref_c, pos_m), abilities, device_type="lift")
