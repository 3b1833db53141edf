"""The AGV bringing the engine to the station and taking it away through the exit.

`goto_c` is the reference state; `none` is the safe state (stop). One ability per
destination (`agv.goto_station`, `agv.goto_exit`): it leaves (`pos_m := moving`) and
arrives. `engine_m` says it carries an engine; the model never changes it.
"""

from __future__ import annotations

from common.model import Domain, Duration, Resource, command, measured

from ._motion import goto_abilities

# How long one effect of the type takes, unless a device's `delay` in hubs.toml says otherwise.
# Leaving a station, or arriving at the next one.
DURATION = Duration.fixed(0.8)

MOVING = "moving"


def agv(name: str = "agv") -> Resource:
    goto_c = command(f"{name}.goto_c", Domain.enum("none", "station", "exit"), "none", "where the AGV is sent")
    pos_m = measured(f"{name}.pos_m", Domain.enum("away", MOVING, "at_station"), "away", "where the AGV is")
    engine_m = measured(f"{name}.engine_m", initial=True, description="an engine is on the AGV")
    abilities = goto_abilities(f"{name}.goto", goto_c, pos_m, {"station": "at_station", "exit": "away"}, MOVING)
    return Resource(name, (goto_c, pos_m, engine_m), abilities, device_type="agv")
