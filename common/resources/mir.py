"""The MiR100 mobile platform carrying the kitted material between kitting and the station.

`goto_c` is the reference state ("be at the station"); `none` is the safe state (stop).
One ability per destination (`mir.goto_station`, `mir.goto_kitting`): it leaves
(`pos_m := moving`) and arrives.
"""

from __future__ import annotations

from common.model import Domain, Duration, Resource, command, measured

from ._motion import goto_abilities

# How long one effect of the type takes, unless a device's `delay` in hubs.toml says otherwise.
# Leaving a station, or arriving at the next one.
DURATION = Duration.fixed(0.8)

MOVING = "moving"


def mir(name: str = "mir") -> Resource:
    goto_c = command(f"{name}.goto_c", Domain.enum("none", "kitting", "station"), "none", "where the MiR is sent")
    pos_m = measured(f"{name}.pos_m", Domain.enum("at_kitting", MOVING, "at_station"), "at_kitting",
                     "where the MiR is")
    abilities = goto_abilities(f"{name}.goto", goto_c, pos_m, {"station": "at_station", "kitting": "at_kitting"},
                               MOVING)
    return Resource(name, (goto_c, pos_m), abilities, device_type="mir")
