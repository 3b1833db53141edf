"""The pneumatic tool changer (rsp): lock and unlock, and which tool it holds.

Who owns which effect (shared with `dock.py`): an effect belongs to the resource whose
measured variable it writes, because that resource's hub (or emulator) is what makes
it happen; its guard may read any resource, because effects model the physical world.

* The changer owns `locked_m` and `tool_m`. Locking while the robot stands at a
  tool's dock pose with that tool at home couples the tool in the same effect
  (`locked_m := true; tool_m := T`); unlocking there releases it in the same effect
  (`locked_m := false; tool_m := none`). Doing both in one effect means the robot can
  never leave between the lock and the tool being seen.
* The dock owns the `*_home_m` presence sensors and reads `tool_m` (see `dock.py`).

`pressure_ok_m` is true in the model (a hub measures it): it guards lock and unlock.
Unlocking a held tool anywhere but its dock pose would drop it; the station forbids that
state by a specification rather than the changer refusing it, so that the controller's
synthesized guards and the planner both see it.

The controller locks only where a tool is picked up (at its dock pose, the tool at home)
and unlocks only where the held tool is put down (or when it holds none). A plan must not
count on an effect waiting: sent on the way to the dock, the lock would close at once on
nothing, while the plan counted on it closing on the tool.
"""

from __future__ import annotations

from collections.abc import Mapping

from common.model import (
    Domain,
    Duration,
    Phase,
    Predicate,
    Resource,
    ability,
    all_of,
    any_of,
    command,
    effect,
    measured,
)

# How long one effect of the type takes, unless a device's `delay` in hubs.toml says otherwise.
# The changer locking or unlocking, with or without a tool.
DURATION = Duration.fixed(0.15)

NO_TOOL = "none"
TOOLS = ("nutrunner", "lift_tool", "filter_tool")


def default_dock_poses() -> dict[str, str]:
    """The robot pose at which each tool sits in the dock: `dock_<tool>`."""
    return {tool: f"dock_{tool}" for tool in TOOLS}


def check_dock_poses(dock_poses: Mapping[str, str] | None) -> dict[str, str]:
    poses = dict(default_dock_poses() if dock_poses is None else dock_poses)
    if set(poses) != set(TOOLS):
        raise ValueError(f"dock_poses must name a pose for each tool {TOOLS}, got {sorted(poses)}")
    return poses


def rsp(name: str = "rsp", robot: str = "ur", dock: str = "dock",
        dock_poses: Mapping[str, str] | None = None) -> Resource:
    """The tool changer on `robot`; the tools live in `dock` at the robot poses `dock_poses[tool]`."""
    slots = check_dock_poses(dock_poses)
    lock_c = command(f"{name}.lock_c", initial=False, description="lock the changer")
    locked_m = measured(f"{name}.locked_m", description="the changer is locked")
    tool_m = measured(f"{name}.tool_m", Domain.enum(NO_TOOL, *TOOLS), description="the tool coupled to the robot")
    pressure_ok_m = measured(f"{name}.pressure_ok_m", initial=True, description="supply pressure is sufficient")

    def at_slot(tool: str) -> Predicate:
        return all_of(f"{robot}.pos_m == {slots[tool]}")

    def picks_up(tool: str) -> Predicate:
        return at_slot(tool) & (tool_m == NO_TOOL) & all_of(f"{dock}.{tool}_home_m")

    def puts_down(tool: str) -> Predicate:
        return at_slot(tool) & (tool_m == tool)

    locking = lock_c & ~locked_m
    unlocking = ~lock_c & locked_m
    lock = ability(
        f"{name}.lock",
        enabled=Phase(~lock_c & ~locked_m, deliberate=f"{lock_c.path} := true",
                      guard=pressure_ok_m & any_of(*(picks_up(t) for t in TOOLS))),
        starting=Phase(locking, effects=[f"{locked_m.path} := true"],
                       guard=pressure_ok_m & ~any_of(*(picks_up(t) for t in TOOLS))),
        finished=lock_c & locked_m,
        extra=[effect(f"{name}.lock.pick_up_{t}", all_of(locking, pressure_ok_m, picks_up(t)),
                      [f"{locked_m.path} := true", f"{tool_m.path} := {t}"]) for t in TOOLS],
    )
    unlock = ability(
        f"{name}.unlock",
        enabled=Phase(lock_c & locked_m, deliberate=f"{lock_c.path} := false",
                      guard=pressure_ok_m & ((tool_m == NO_TOOL) | any_of(*(puts_down(t) for t in TOOLS)))),
        starting=Phase(unlocking, effects=[f"{locked_m.path} := false"],
                       guard=pressure_ok_m & ~any_of(*(puts_down(t) for t in TOOLS))),
        finished=~lock_c & ~locked_m,
        extra=[effect(f"{name}.unlock.put_down_{t}", all_of(unlocking, pressure_ok_m, puts_down(t)),
                      [f"{locked_m.path} := false", f"{tool_m.path} := {NO_TOOL}"]) for t in TOOLS],
    )
    variables = (lock_c, locked_m, tool_m, pressure_ok_m)
    return Resource(name, variables, (lock, unlock), device_type="rsp",
                    parameters={"robot": robot, "dock": dock, "dock_poses": slots})
