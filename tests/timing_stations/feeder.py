"""The smallest station whose plan can race a device (issue 21): a robot takes a box from a feeder.

A robot `r` (poses home, at_feeder, at_pallet), a vacuum gripper `g` and a box feeder `f`.
The feeder's sensor `f.present_m` reports the box taken only while the robot stays at the
feeder with its vacuum on (`f.taken`, an effect of the feeder that reads the robot and the
gripper). The box is tracked waiting -> on_feeder -> held -> on_pallet; one operation, `Place`.

With the feeder's sensor slower than the robot's first move effect (`FEEDER_DELAY` >
`ROBOT_DELAY`, as in hubs.toml next to this module), a plan that sends the robot on while
the sensor's effect is due loses that effect: the devices cannot follow it. Written with
`common.model` only, as a station outside this repository would be.

`build_model(unavoidable=True)`: the robot's own program leaves the feeder for the pallet as
soon as the vacuum holds there (an automatic transition of the robot, which the controller
fires at once and no plan can hold back), so the robot always leaves before the sensor reports
the box taken: no plan the devices can follow.
"""

from __future__ import annotations

from common.model import (
    Ability,
    Domain,
    Model,
    Phase,
    Resource,
    ability,
    automatic,
    command,
    effect,
    estimated,
    measured,
    operation,
    tracking,
)

POSES = ("home", "at_feeder", "at_pallet")
UNKNOWN = "unknown"
ROBOT_DELAY = 0.15  # seconds a robot move's effect takes (each of leaving and arriving)
GRIPPER_DELAY = 0.1
FEEDER_DELAY = 0.2  # longer than ROBOT_DELAY: the race


def robot(name: str, delay: float = ROBOT_DELAY, gripper_name: str = "", leaves_when_gripped: bool = False) -> Resource:
    """A robot sent to named poses; it reports `unknown` between them. `leaves_when_gripped`: its program
    sends it from the feeder to the pallet as soon as the gripper's vacuum holds there."""
    ref_c = command(f"{name}.ref_c", Domain.enum(*POSES), "home", "the pose the robot is sent to")
    pos_m = measured(f"{name}.pos_m", Domain.enum(*POSES, UNKNOWN), "home", "the pose it is at, or unknown")

    def move_to(target: str) -> Ability:
        at_rest_elsewhere = " || ".join(f"(pos_m == {p} && ref_c == {p})" for p in POSES if p != target)
        at_rest_elsewhere = at_rest_elsewhere.replace("pos_m", pos_m.path).replace("ref_c", ref_c.path)
        sent = f"{ref_c.path} == {target}"
        return ability(
            f"{name}.move_to_{target}",
            enabled=Phase(at_rest_elsewhere, deliberate=f"{ref_c.path} := {target}"),
            starting=Phase(f"{sent} && {pos_m.path} != {target} && {pos_m.path} != {UNKNOWN}",
                           effects=[f"{pos_m.path} := {UNKNOWN}"]),
            executing=Phase(f"{sent} && {pos_m.path} == {UNKNOWN}", effects=[f"{pos_m.path} := {target}"]),
            finished=f"{sent} && {pos_m.path} == {target}",
        )

    abilities = tuple(move_to(p) for p in POSES)
    if leaves_when_gripped:
        at_feeder = f"{pos_m.path} == at_feeder && {ref_c.path} == at_feeder"
        leave = automatic(f"{name}.leave_when_gripped", f"{at_feeder} && {gripper_name}.vac_m",
                          f"{ref_c.path} := at_pallet")
        abilities += (ability(f"{name}.leave_when_gripped", enabled=f"{at_feeder} && {gripper_name}.vac_m",
                              extra=[leave]),)
    return Resource(name, (ref_c, pos_m), abilities, device_type="timing_robot",
                    parameters={"emulated_delay": delay, "safe_state": {}})


def vacuum_gripper(name: str, robot_name: str, delay: float = GRIPPER_DELAY) -> Resource:
    """A vacuum gripper on the robot; the controller lets go only over the pallet (elsewhere the box would fall)."""
    vac_c = command(f"{name}.vac_c", initial=False, description="switch the vacuum on")
    vac_m = measured(f"{name}.vac_m", description="the vacuum holds")
    grip = ability(f"{name}.grip",
                   enabled=Phase(f"!{vac_c.path} && !{vac_m.path}", deliberate=f"{vac_c.path} := true"),
                   executing=Phase(f"{vac_c.path} && !{vac_m.path}", effects=[f"{vac_m.path} := true"]),
                   finished=f"{vac_c.path} && {vac_m.path}")
    release = ability(f"{name}.release",
                      enabled=Phase(f"{vac_c.path} && {vac_m.path}", deliberate=f"{vac_c.path} := false",
                                    guard=f"{robot_name}.pos_m == at_pallet"),
                      executing=Phase(f"!{vac_c.path} && {vac_m.path}", effects=[f"{vac_m.path} := false"]),
                      finished=f"!{vac_c.path} && !{vac_m.path}")
    return Resource(name, (vac_c, vac_m), (grip, release), device_type="vacuum_gripper",
                    parameters={"emulated_delay": delay, "safe_state": {}})


def feeder(name: str, robot_name: str, gripper_name: str, delay: float = FEEDER_DELAY) -> Resource:
    """A box feeder: `feed` brings a box; the sensor reports it taken while the robot holds it there."""
    feed_c = command(f"{name}.feed_c", initial=False, description="bring a box")
    present_m = measured(f"{name}.present_m", initial=True, description="a box stands at the pick position")
    feed = ability(f"{name}.feed",
                   enabled=Phase(f"!{feed_c.path} && !{present_m.path}", deliberate=f"{feed_c.path} := true"),
                   executing=Phase(f"{feed_c.path} && !{present_m.path}", effects=[f"{present_m.path} := true"]),
                   finished=Phase(f"{feed_c.path} && {present_m.path}", automatic=f"{feed_c.path} := false"))
    taken_guard = (f"{present_m.path} && !{feed_c.path} && {robot_name}.pos_m == at_feeder"
                   f" && {gripper_name}.vac_m")
    taken = ability(f"{name}.taken", executing=f"{present_m.path}", finished=f"!{present_m.path}",
                    extra=[effect(f"{name}.taken.effect", taken_guard, [f"{present_m.path} := false"])])
    return Resource(name, (feed_c, present_m), (feed, taken), device_type="box_feeder",
                    parameters={"emulated_delay": delay, "safe_state": {"feed_c": False}})


BOX = Domain.enum("waiting", "on_feeder", "held", "on_pallet")


def build_model(*, unavoidable: bool = False, feeder_delay: float = FEEDER_DELAY,
                robot_delay: float = ROBOT_DELAY) -> Model:
    box = estimated("cell.box_e", BOX, "waiting", "where the box is")
    records = (
        tracking("cell.box_arrived", "cell.box_e == waiting && f.present_m", "cell.box_e := on_feeder"),
        tracking("cell.box_taken", "cell.box_e == on_feeder && !f.present_m && g.vac_m", "cell.box_e := held"),
        tracking("cell.box_placed", "cell.box_e == held && r.pos_m == at_pallet && !g.vac_m",
                 "cell.box_e := on_pallet"),
    )
    place = operation("Place", "cell.box_e == on_feeder", "cell.box_e == on_pallet")
    resources = (robot("r", robot_delay, "g", leaves_when_gripped=unavoidable), vacuum_gripper("g", "r"),
                 feeder("f", "r", "g", feeder_delay))
    return Model("timing_feeder", resources, (box,), records, (place,))


def build_unavoidable_model() -> Model:
    return build_model(unavoidable=True)
