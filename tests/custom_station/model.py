"""A station whose device types are all its own (statehub has a driver for none): a shuttle and a press.

The shuttle carries a part from the loading place to the press, which presses it; then the
shuttle brings it back. Both run emulated from this model alone (tests/custom_station/hubs.toml).
"""

from __future__ import annotations

from common.model import Domain, Model, Phase, Resource, ability, command, estimated, measured, operation, tracking

PLACES = Domain.enum("load", "press")


def shuttle(name: str) -> Resource:
    """A carriage sent to a place; it reports the place it is at, or `moving`."""
    to_c = command(f"{name}.to_c", PLACES, "load", "the place the shuttle is sent to")
    at_m = measured(f"{name}.at_m", Domain.enum("load", "press", "moving"), "load", "where the shuttle is")
    abilities = tuple(
        ability(f"{name}.go_{place}",
                enabled=Phase((to_c != place) & (at_m == other), deliberate=f"{to_c.path} := {place}"),
                starting=Phase((to_c == place) & (at_m == other), effects=[f"{at_m.path} := moving"]),
                executing=Phase((to_c == place) & (at_m == "moving"), effects=[f"{at_m.path} := {place}"]),
                finished=(to_c == place) & (at_m == place))
        for place, other in (("load", "press"), ("press", "load")))
    return Resource(name, (to_c, at_m), abilities, device_type="shuttle",
                    parameters={"emulated_delay": 0.2, "safe_state": {}})


def press(name: str) -> Resource:
    """A press stroke: commanded down, it reports down, and comes up when the command is withdrawn."""
    down_c = command(f"{name}.down_c", initial=False, description="press")
    down_m = measured(f"{name}.down_m", description="the ram is down")
    stroke = ability(
        f"{name}.stroke",
        enabled=Phase(~down_c & ~down_m, deliberate=f"{down_c.path} := true"),
        executing=Phase(down_c & ~down_m, effects=[f"{down_m.path} := true"]),
        finished=Phase(down_c & down_m, automatic=f"{down_c.path} := false"),
        resetting=Phase(~down_c & down_m, effects=[f"{down_m.path} := false"]),
    )
    return Resource(name, (down_c, down_m), (stroke,), device_type="press",
                    parameters={"emulated_delay": 0.2, "safe_state": {"down_c": False}})


PART = Domain.enum("raw", "at_press", "pressed", "back")


def build_model() -> Model:
    part = estimated("cell.part_e", PART, "raw", "the part on the shuttle")
    records = (
        tracking("cell.part_arrived", "cell.part_e == raw && shuttle.at_m == press", "cell.part_e := at_press"),
        tracking("cell.part_pressed", "cell.part_e == at_press && press.down_m && shuttle.at_m == press",
                 "cell.part_e := pressed"),
        tracking("cell.part_back", "cell.part_e == pressed && !press.down_m && shuttle.at_m == load",
                 "cell.part_e := back"),
    )
    operations = (
        operation("ToPress", "cell.part_e == raw", "cell.part_e == at_press"),
        operation("Press", "cell.part_e == at_press", "cell.part_e == pressed"),
        operation("Return", "cell.part_e == pressed", "cell.part_e == back"),
    )
    return Model("custom_station", (shuttle("shuttle"), press("press")), (part,), records, operations)
