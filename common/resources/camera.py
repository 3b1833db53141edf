"""The safety camera: which zone the operator is in (outside, shared, robot).

In the model the operator goes where the instruction sends them: `task_zones` maps
each operator task to the zone it is done in; any other instruction (including none)
means the operator is outside. One ability per zone (`cam.sees_shared`, ...): while
the operator is instructed into the zone but not yet seen there, the camera sees them
arrive (an effect).
"""

from __future__ import annotations

from collections.abc import Mapping

from common.model import Ability, Domain, Duration, In, Not, Phase, Predicate, Resource, ability, measured

# How long one effect of the type takes, unless a device's `delay` in hubs.toml says otherwise.
# Seeing the operator in another zone.
DURATION = Duration.fixed(0.1)

ZONES = ("outside", "shared", "robot")
OUTSIDE = "outside"


def camera(name: str = "cam", operator: str = "human", task_zones: Mapping[str, str] | None = None) -> Resource:
    zones_of_tasks = dict(task_zones or {})
    unknown = {z for z in zones_of_tasks.values() if z not in ZONES or z == OUTSIDE}
    if unknown:
        raise ValueError(f"task_zones may map tasks to {ZONES[1:]}, not {sorted(unknown)}")
    zone_m = measured(f"{name}.zone_m", Domain.enum(*ZONES), OUTSIDE, "the zone the operator is seen in")
    instruction = f"{operator}.instr_c"
    abilities: list[Ability] = []
    for zone in ZONES[1:]:
        tasks = tuple(t for t, z in zones_of_tasks.items() if z == zone)
        if tasks:
            abilities.append(_sees(name, zone_m.path, zone, In(instruction, tasks) & (zone_m != zone)))
    if zones_of_tasks:
        anywhere_inside = Not(In(instruction, tuple(zones_of_tasks)))
        abilities.append(_sees(name, zone_m.path, OUTSIDE, anywhere_inside & (zone_m != OUTSIDE)))
    return Resource(name, (zone_m,), tuple(abilities), device_type="camera",
                    parameters={"operator": operator, "task_zones": zones_of_tasks})


def _sees(name: str, zone_path: str, zone: str, instructed_there: Predicate) -> Ability:
    return ability(
        f"{name}.sees_{zone}",
        executing=Phase(instructed_there, effects=[f"{zone_path} := {zone}"]),
        finished=f"{zone_path} == {zone}",
    )
