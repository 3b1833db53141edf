"""The tool dock: one presence sensor per tool slot, nothing commanded.

Effects (ownership rule in `rsp.py`: the dock writes only its own sensors):

* a tool leaves home when the robot has coupled it (`rsp.tool_m == T`, which the
  changer sets when it locks at the tool's dock pose) and moved away from that pose;
* it returns home once it is no longer on the robot (the changer releases it only at
  its own dock pose, so a tool that left the changer is back in its slot).

A tool can also be handheld: while the operator is instructed to do one of
`handheld_tasks[T]` the operator has taken T out of its slot, and puts it back when
the instruction ends. The changer cannot pick a tool up while it is not home.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from common.model import FALSE, Ability, Duration, In, Phase, Predicate, Resource, ability, all_of, any_of, measured

from .rsp import TOOLS, check_dock_poses

# How long one effect of the type takes, unless a device's `delay` in hubs.toml says otherwise.
# A slot's presence sensor seeing a tool arrive or leave.
DURATION = Duration.fixed(0.1)


def dock(name: str = "dock", robot: str = "ur", changer: str = "rsp", dock_poses: Mapping[str, str] | None = None,
         operator: str = "human", handheld_tasks: Mapping[str, Iterable[str]] | None = None) -> Resource:
    slots = check_dock_poses(dock_poses)
    handheld = {tool: tuple(tasks) for tool, tasks in (handheld_tasks or {}).items()}
    unknown_tools = set(handheld) - set(TOOLS)
    if unknown_tools:
        raise ValueError(f"handheld_tasks names unknown tools {sorted(unknown_tools)}; tools are {TOOLS}")
    variables = tuple(measured(f"{name}.{tool}_home_m", initial=True, description=f"the {tool} is in its slot")
                      for tool in TOOLS)
    abilities: list[Ability] = []
    for tool in TOOLS:
        home = all_of(f"{name}.{tool}_home_m")
        on_robot = all_of(f"{changer}.tool_m == {tool}")
        carried_off = on_robot & all_of(f"{robot}.pos_m != {slots[tool]}")
        in_hand: Predicate = In(f"{operator}.instr_c", handheld[tool]) if handheld.get(tool) else FALSE
        not_in_hand = () if in_hand == FALSE else (~in_hand,)
        abilities.append(ability(
            f"{name}.{tool}_leaves",
            executing=Phase(home & any_of(carried_off, in_hand), effects=[f"{name}.{tool}_home_m := false"]),
            finished=~home,
        ))
        abilities.append(ability(
            f"{name}.{tool}_returns",
            executing=Phase(all_of(~home, f"{changer}.tool_m != {tool}", *not_in_hand),
                            effects=[f"{name}.{tool}_home_m := true"]),
            finished=home,
        ))
    return Resource(name, variables, tuple(abilities), device_type="dock",
                    parameters={"robot": robot, "changer": changer, "dock_poses": slots,
                                "operator": operator, "handheld_tasks": handheld})
