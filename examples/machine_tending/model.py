"""A machine-tending cell: one robot feeds a CNC machine from an infeed conveyor and clears it to an outfeed.

The story of each part k (`PARTS`), one planning operation per step:

1. `FeedPart<k>`: the infeed conveyor brings the raw part to its end stop, where the
   robot picks it (it runs only while the robot is out of the pick zone).
2. `LoadPart<k>`: the CNC door opens, the robot picks the part from the infeed, carries
   it into the machine, the chuck clamps it, the gripper lets go.
3. `MachinePart<k>`: the robot leaves the machine, the door closes, the machining cycle
   runs (the spindle turns only behind the closed door).
4. `UnloadPart<k>`: the door opens, the robot grips the finished part in the chuck, the
   chuck lets go, the robot takes it out.
5. `DeliverPart<k>`: the robot sets the part on the outfeed conveyor and lets go.
6. `ShipPart<k>`: the outfeed carries it away (only while the robot is clear of it).

then `CloseDoor` and `RobotHome`. The next part is fed while the current one is
machined, and the operations of several parts overlap wherever the cell allows.

Device types the standard templates lack are defined here, with the same modelling API
(`ability`/`Phase`) as common/resources, so this module is all a deployment needs:
`conveyor` (infeed and outfeed), `gripper`, `cnc` (chuck and spindle) and `cnc_door`.
They run in `emulate` mode from this model alone (examples/machine_tending/hubs.toml).

Ownership of effects follows common/resources/rsp.py: an effect belongs to the resource
whose measured variable it writes; its guard may read any resource (effects are the
physical world). Where a part passes from one device to another the receiving device's
effect reads the giver's state in the same step (the chuck clamps the part the gripper
holds in it), so the hand-over is never a race between two effects.

Global estimated state lives under `cell.`: `cell.part<k>_e` follows each part through
`PART_STAGES`, recorded by tracking abilities from what the sensors show.
"""

from __future__ import annotations

from collections.abc import Mapping

from common.model import (
    Ability,
    Domain,
    Model,
    Operation,
    Phase,
    Predicate,
    Resource,
    Specification,
    Value,
    ability,
    all_of,
    any_of,
    command,
    effect,
    estimated,
    forbid,
    measured,
    operation,
    tracking,
)
from common.resources import ur

# --- the device types of this cell ------------------------------------------------------


def infeed_conveyor(name: str, robot: str, gripper: str, pick_pose: str) -> Resource:
    """A conveyor that brings one part at a time to its end stop, where the robot picks it at `pick_pose`.

    | ability | predicate                   | control actions          | effects                 |
    |---------|-----------------------------|--------------------------|-------------------------|
    | feed    | !run_c && !present_m        | run_c := T (deliberate)  | -                       |
    |         | run_c && !present_m         | -                        | present_m := T (arrives) |
    |         | run_c && present_m          | run_c := F (automatic)   | -                       |
    | taken   | present_m, gripped there    | -                        | present_m := F          |
    """
    run_c = command(f"{name}.run_c", initial=False, description="run the belt")
    present_m = measured(f"{name}.present_m", description="a part stands at the end stop")
    gripped_there = all_of(f"{robot}.pos_m == {pick_pose}", f"{gripper}.part_m")
    feed = ability(
        f"{name}.feed",
        enabled=Phase(~run_c & ~present_m, deliberate=f"{run_c.path} := true"),
        executing=Phase(run_c & ~present_m, effects=[f"{present_m.path} := true"]),
        finished=Phase(run_c & present_m, automatic=f"{run_c.path} := false"),
    )
    # The end-stop sensor counts a part as gone once the gripper holds it.
    taken = ability(f"{name}.taken", executing=Phase(present_m & gripped_there, effects=[f"{present_m.path} := false"]),
                    finished=~present_m)
    return Resource(name, (run_c, present_m), (feed, taken), device_type="conveyor",
                    parameters={"role": "infeed", "robot": robot, "gripper": gripper, "pose": pick_pose,
                                "emulated_delay": 0.6, "safe_state": {"run_c": False}})


def outfeed_conveyor(name: str, robot: str, gripper: str, place_pose: str) -> Resource:
    """A conveyor that carries away the part the robot set down at `place_pose`.

    | ability     | predicate                        | control actions          | effects          |
    |-------------|----------------------------------|--------------------------|------------------|
    | placed      | !present_m, robot there with part | -                       | present_m := T   |
    | carry_away  | !run_c && present_m              | run_c := T (deliberate)  | -                |
    |             | run_c && present_m               | -                        | present_m := F   |
    |             | run_c && !present_m              | run_c := F (automatic)   | -                |
    """
    run_c = command(f"{name}.run_c", initial=False, description="run the belt")
    present_m = measured(f"{name}.present_m", description="a part stands at the place position")
    # The sensor sees the part as soon as it stands on the belt, still in the gripper.
    set_down = all_of(f"{robot}.pos_m == {place_pose}", f"{gripper}.part_m")
    placed = ability(f"{name}.placed", executing=Phase(~present_m & set_down, effects=[f"{present_m.path} := true"]),
                     finished=present_m)
    carry_away = ability(
        f"{name}.carry_away",
        enabled=Phase(~run_c & present_m, deliberate=f"{run_c.path} := true"),
        executing=Phase(run_c & present_m, effects=[f"{present_m.path} := false"]),
        finished=Phase(run_c & ~present_m, automatic=f"{run_c.path} := false"),
    )
    return Resource(name, (run_c, present_m), (placed, carry_away), device_type="conveyor",
                    parameters={"role": "outfeed", "robot": robot, "gripper": gripper, "pose": place_pose,
                                "emulated_delay": 0.6, "safe_state": {"run_c": False}})


def gripper(name: str, robot: str, grips: Mapping[str, object]) -> Resource:
    """A two-finger gripper on `robot`; `grips[pose]` says when a part lies ready to be gripped at that pose.

    Closing at such a pose closes on the part (`part_m := true`, one effect); anywhere
    else it closes empty. Opening always lets the part go: where that is allowed is the
    station's specification, not the gripper's business.

    The controller closes it only where it grips a part: sent on the way, the fingers would
    close at once on nothing while the plan counted on them closing on the part (as the tool
    changer's lock in common/resources/rsp.py).
    """
    close_c = command(f"{name}.close_c", initial=False, description="close the fingers")
    closed_m = measured(f"{name}.closed_m", description="the fingers are closed")
    part_m = measured(f"{name}.part_m", description="a part is between the fingers")
    closing = close_c & ~closed_m
    on_a_part = {pose: all_of(f"{robot}.pos_m == {pose}", ready) for pose, ready in grips.items()}
    close = ability(
        f"{name}.close",
        enabled=Phase(~close_c & ~closed_m, deliberate=f"{close_c.path} := true", guard=any_of(*on_a_part.values())),
        starting=Phase(closing, effects=[f"{closed_m.path} := true"], guard=~any_of(*on_a_part.values())),
        finished=close_c & closed_m,
        extra=[effect(f"{name}.close.grip_at_{pose}", closing & there, [f"{closed_m.path} := true",
                                                                         f"{part_m.path} := true"])
               for pose, there in on_a_part.items()],
    )
    release = ability(
        f"{name}.open",
        enabled=Phase(close_c & closed_m, deliberate=f"{close_c.path} := false"),
        starting=Phase(~close_c & closed_m, effects=[[f"{closed_m.path} := false", f"{part_m.path} := false"]]),
        finished=~close_c & ~closed_m,
    )
    # Losing the command must not drop a part: the fingers keep their grip (empty safe state).
    return Resource(name, (close_c, closed_m, part_m), (close, release), device_type="gripper",
                    parameters={"robot": robot, "grips": dict(grips), "emulated_delay": 0.2, "safe_state": {}})


CHUCK_PARTS = Domain.enum("none", "raw", "finished")


def cnc(name: str, robot: str, gripper: str, load_pose: str) -> Resource:
    """The machine: a chuck that clamps the part the robot holds in it at `load_pose`, and the machining cycle.

    `part_m` is the machine's own view of its chuck: empty, a raw part (clamped from the
    gripper), or a finished one (its program ran to the end). The controller closes the
    chuck only on a part the robot holds in it and opens it only to hand a finished part
    back, so that no plan counts on the chuck waiting (see `gripper`).

    | ability | predicate                            | control actions           | effects                  |
    |---------|--------------------------------------|---------------------------|--------------------------|
    | clamp   | !clamp_c && !clamped_m               | clamp_c := T (deliberate) | -                        |
    |         | clamp_c && !clamped_m                | -                         | clamped_m := T, takes    |
    |         |                                      |                           | the part the robot holds |
    | unclamp | clamp_c && clamped_m                 | clamp_c := F (deliberate) | -                        |
    |         | !clamp_c && clamped_m                | -                         | clamped_m := F, hands    |
    |         |                                      |                           | the part to the gripper  |
    | cycle   | !cycle_c && !running_m, raw, clamped | cycle_c := T (deliberate) | -                        |
    |         | cycle_c && !running_m && raw         | -                         | running_m := T           |
    |         | cycle_c && running_m && raw          | -                         | part_m := finished       |
    |         | cycle_c && finished                  | cycle_c := F (automatic)  | -                        |
    |         | !cycle_c && running_m                | -                         | running_m := F           |
    """
    clamp_c = command(f"{name}.clamp_c", initial=False, description="close the chuck")
    clamped_m = measured(f"{name}.clamped_m", description="the chuck is closed")
    part_m = measured(f"{name}.part_m", CHUCK_PARTS, "none", "what the chuck holds")
    cycle_c = command(f"{name}.cycle_c", initial=False, description="run the machining program")
    running_m = measured(f"{name}.running_m", description="the spindle turns")
    held_in_chuck = all_of(f"{robot}.pos_m == {load_pose}", f"{gripper}.part_m")
    clamping, unclamping = clamp_c & ~clamped_m, ~clamp_c & clamped_m
    takes_part = held_in_chuck & (part_m == "none")
    hands_over = held_in_chuck & (part_m == "finished")
    clamp = ability(
        f"{name}.clamp",
        enabled=Phase(~clamp_c & ~clamped_m, deliberate=f"{clamp_c.path} := true", guard=takes_part),
        starting=Phase(clamping, effects=[f"{clamped_m.path} := true"], guard=~takes_part),
        finished=clamp_c & clamped_m,
        extra=[effect(f"{name}.clamp.take_part", clamping & takes_part,
                      [f"{clamped_m.path} := true", f"{part_m.path} := raw"])],
    )
    unclamp = ability(
        f"{name}.unclamp",
        enabled=Phase(clamp_c & clamped_m, deliberate=f"{clamp_c.path} := false", guard=hands_over),
        starting=Phase(unclamping, effects=[f"{clamped_m.path} := false"], guard=~hands_over),
        finished=~clamp_c & ~clamped_m,
        extra=[effect(f"{name}.unclamp.hand_over", unclamping & hands_over,
                      [f"{clamped_m.path} := false", f"{part_m.path} := none"])],
    )
    raw = part_m == "raw"
    cycle = ability(
        f"{name}.cycle",
        enabled=Phase(~cycle_c & ~running_m & raw & clamped_m, deliberate=f"{cycle_c.path} := true"),
        starting=Phase(cycle_c & ~running_m & raw, effects=[f"{running_m.path} := true"]),
        executing=Phase(cycle_c & running_m & raw, effects=[f"{part_m.path} := finished"]),
        finished=Phase(cycle_c & (part_m == "finished"), automatic=f"{cycle_c.path} := false"),
        resetting=Phase(~cycle_c & running_m, effects=[f"{running_m.path} := false"]),
    )
    variables = (clamp_c, clamped_m, part_m, cycle_c, running_m)
    # Without commands the machine holds its program (feed hold); the chuck keeps its grip.
    return Resource(name, variables, (clamp, unclamp, cycle), device_type="cnc",
                    parameters={"robot": robot, "gripper": gripper, "pose": load_pose, "emulated_delay": 0.5,
                                "safe_state": {"cycle_c": False}})


DOOR_POSITIONS = Domain.enum("closed", "moving", "open")


def cnc_door(name: str) -> Resource:
    """The machine's automatic door: commanded open or closed, measured closed, moving or open."""
    open_c = command(f"{name}.open_c", initial=False, description="open the door")
    pos_m = measured(f"{name}.pos_m", DOOR_POSITIONS, "closed", "where the door is")
    opening, closing = open_c, ~open_c
    door_open = ability(
        f"{name}.open",
        enabled=Phase(~open_c & (pos_m == "closed"), deliberate=f"{open_c.path} := true"),
        starting=Phase(opening & (pos_m == "closed"), effects=[f"{pos_m.path} := moving"]),
        executing=Phase(opening & (pos_m == "moving"), effects=[f"{pos_m.path} := open"]),
        finished=opening & (pos_m == "open"),
    )
    door_close = ability(
        f"{name}.close",
        enabled=Phase(open_c & (pos_m == "open"), deliberate=f"{open_c.path} := false"),
        starting=Phase(closing & (pos_m == "open"), effects=[f"{pos_m.path} := moving"]),
        executing=Phase(closing & (pos_m == "moving"), effects=[f"{pos_m.path} := closed"]),
        finished=closing & (pos_m == "closed"),
    )
    # A door that lost its commands stops where it is: the safe state is no new command.
    return Resource(name, (open_c, pos_m), (door_open, door_close), device_type="cnc_door",
                    parameters={"emulated_delay": 0.4, "safe_state": {}})


# --- the cell --------------------------------------------------------------------------
PART_COUNT = 4
PARTS = tuple(range(1, PART_COUNT + 1))
PART_STAGES = Domain.enum("waiting", "at_infeed", "picked", "loaded", "machined", "unloaded", "delivered",
                          "shipped")

HOME = "home"
ABOVE_INFEED, AT_INFEED = "above_infeed", "at_infeed"
CNC_FRONT, IN_CNC = "cnc_front", "in_cnc"
ABOVE_OUTFEED, AT_OUTFEED = "above_outfeed", "at_outfeed"
POSES = (HOME, ABOVE_INFEED, AT_INFEED, CNC_FRONT, IN_CNC, ABOVE_OUTFEED, AT_OUTFEED)
# Each work position (pick, chuck, place) is reached only from its approach pose.
ALLOWED_MOVES = (
    (HOME, ABOVE_INFEED), (ABOVE_INFEED, AT_INFEED),
    (HOME, CNC_FRONT), (CNC_FRONT, IN_CNC),
    (HOME, ABOVE_OUTFEED), (ABOVE_OUTFEED, AT_OUTFEED),
    (ABOVE_INFEED, CNC_FRONT), (CNC_FRONT, ABOVE_OUTFEED),
)


def part(k: int) -> str:
    return f"cell.part{k}_e"


def build_model() -> Model:
    resources = (
        ur("ur", POSES, ALLOWED_MOVES, HOME),
        gripper("gripper", "ur", {AT_INFEED: "infeed.present_m", IN_CNC: "cnc.part_m == finished"}),
        infeed_conveyor("infeed", "ur", "gripper", AT_INFEED),
        outfeed_conveyor("outfeed", "ur", "gripper", AT_OUTFEED),
        cnc("cnc", "ur", "gripper", IN_CNC),
        cnc_door("door"),
    )
    parts = tuple(estimated(part(k), PART_STAGES, "waiting", f"part {k}") for k in PARTS)
    return Model("machine_tending", resources, parts, _tracking(), _operations(), _specifications())


def _tracking() -> tuple[Ability, ...]:
    abilities: list[Ability] = []
    for k in PARTS:
        others = [j for j in PARTS if j != k]
        # Parts come in order: part k is the one that arrives once every earlier part has.
        arrives = all_of(f"{part(k)} == waiting", "infeed.present_m",
                         *(f"{part(j)} != waiting" for j in PARTS if j < k),
                         *(f"{part(j)} != at_infeed" for j in others))
        steps = (
            ("arrived", arrives, "at_infeed"),
            ("picked", all_of(f"{part(k)} == at_infeed", "!infeed.present_m"), "picked"),
            ("loaded", all_of(f"{part(k)} == picked", "cnc.part_m == raw", "!gripper.part_m",
                              f"ur.pos_m == {IN_CNC}"), "loaded"),
            ("machined", all_of(f"{part(k)} == loaded", "cnc.part_m == finished"), "machined"),
            ("unloaded", all_of(f"{part(k)} == machined", "cnc.part_m == none", "gripper.part_m"), "unloaded"),
            ("delivered", all_of(f"{part(k)} == unloaded", "!gripper.part_m", f"ur.pos_m == {AT_OUTFEED}",
                                 "outfeed.present_m"), "delivered"),
            ("shipped", all_of(f"{part(k)} == delivered", "!outfeed.present_m"), "shipped"),
        )
        abilities += [tracking(f"cell.part{k}_{name}", guard, f"{part(k)} := {stage}") for name, guard, stage in steps]
    return tuple(abilities)


def _stage_in(k: int, *stages: Value) -> Predicate:
    return any_of(*(f"{part(k)} == {s}" for s in stages))


def _operations() -> tuple[Operation, ...]:
    operations: list[Operation] = []
    for k in PARTS:
        # One part at the end stop and one in the chuck at a time: part k follows part k-1.
        previous_fed = _stage_in(k - 1, *PART_STAGES.values[2:]) if k > 1 else True
        previous_out = _stage_in(k - 1, "unloaded", "delivered", "shipped") if k > 1 else True
        operations += [
            operation(f"FeedPart{k}", all_of(f"{part(k)} == waiting", previous_fed), f"{part(k)} == at_infeed",
                      description=f"the infeed brings raw part {k} to its end stop"),
            operation(f"LoadPart{k}", all_of(f"{part(k)} == at_infeed", previous_out), f"{part(k)} == loaded",
                      description=f"the robot loads part {k} into the chuck"),
            operation(f"MachinePart{k}", f"{part(k)} == loaded", f"{part(k)} == machined",
                      description=f"the door closes and the machine runs its cycle on part {k}"),
            operation(f"UnloadPart{k}", f"{part(k)} == machined", f"{part(k)} == unloaded",
                      description=f"the robot takes finished part {k} out of the chuck"),
            operation(f"DeliverPart{k}", f"{part(k)} == unloaded", f"{part(k)} == delivered",
                      description=f"the robot sets part {k} on the outfeed"),
            operation(f"ShipPart{k}", f"{part(k)} == delivered", f"{part(k)} == shipped",
                      description=f"the outfeed carries part {k} away"),
        ]
    all_out = all_of(*(_stage_in(k, "unloaded", "delivered", "shipped") for k in PARTS))
    all_delivered = all_of(*(_stage_in(k, "delivered", "shipped") for k in PARTS))
    operations += [
        operation("CloseDoor", all_out, "door.pos_m == closed && !door.open_c",
                  description="the machine is closed once the last part is out"),
        operation("RobotHome", all_delivered, f"ur.pos_m == {HOME} && !gripper.close_c",
                  description="the robot goes home with its gripper open"),
    ]
    return tuple(operations)


def _zone(pose: str, approach: str) -> Predicate:
    """The robot at a work pose, sent there, or between it and its approach pose.

    Between poses only the target is known, so every move to the approach pose counts
    (conservative: also one coming from elsewhere)."""
    return any_of(f"ur.pos_m == {pose}", f"ur.ref_pos_c == {pose}",
                  all_of(f"ur.ref_pos_c == {approach}", "ur.pos_m == unknown"))


def _specifications() -> tuple[Specification, ...]:
    # The machine and the belts sense a part, not which one: the cell's rules keep raw and
    # finished parts apart, so that what the tracking records is what happened.
    raw_in_gripper = any_of(*(f"{part(k)} == picked" for k in PARTS)) & all_of("gripper.part_m")
    finished_in_gripper = any_of(*(f"{part(k)} == unloaded" for k in PARTS)) & all_of("gripper.part_m")
    in_machine = _zone(IN_CNC, CNC_FRONT)
    at_pick = _zone(AT_INFEED, ABOVE_INFEED)
    at_place = _zone(AT_OUTFEED, ABOVE_OUTFEED)
    may_let_go = any_of(all_of(f"ur.pos_m == {IN_CNC}", "cnc.clamped_m"),
                        all_of(f"ur.pos_m == {AT_OUTFEED}", "outfeed.present_m"))
    moving_to = {pose: all_of(f"ur.ref_pos_c == {pose}", f"ur.pos_m != {pose}")
                 for pose in (AT_INFEED, IN_CNC, AT_OUTFEED)}
    return (
        forbid("robot_in_machine_while_door_not_open",
               in_machine & any_of("door.pos_m != open", "!door.open_c"),
               "the robot is never inside the machine while its door moves, closes or is closed"),
        forbid("spindle_runs_with_door_open", all_of("cnc.running_m", "door.pos_m != closed"),
               "the spindle never turns unless the door is closed"),
        forbid("chuck_opens_while_spindle_runs", all_of("cnc.running_m", "!cnc.clamp_c"),
               "the chuck never lets go of a part the spindle turns"),
        forbid("infeed_runs_with_robot_at_pick", all_of("infeed.run_c") & at_pick,
               "the infeed belt never moves while the robot is in its pick zone"),
        forbid("outfeed_runs_with_robot_at_place", all_of("outfeed.run_c") & at_place,
               "the outfeed belt never moves while the robot is in its place zone"),
        forbid("part_dropped", all_of("!gripper.close_c", "gripper.part_m") & ~may_let_go,
               "the gripper lets go of a part only in the closed chuck or on the outfeed"),
        forbid("part_carried_into_occupied_pick", moving_to[AT_INFEED] & all_of("gripper.part_m"),
               "the robot never brings a part into the infeed's pick position"),
        forbid("part_carried_into_occupied_chuck", moving_to[IN_CNC] & all_of("gripper.part_m", "cnc.part_m != none"),
               "the robot never brings a part to a chuck that holds one"),
        forbid("part_carried_onto_occupied_place", moving_to[AT_OUTFEED] & all_of("gripper.part_m",
                                                                                   "outfeed.present_m"),
               "the robot never sets a part on the outfeed where one still stands"),
        forbid("part_torn_from_chuck",
               all_of("gripper.part_m", "cnc.clamped_m", f"ur.pos_m == {IN_CNC}", f"ur.ref_pos_c != {IN_CNC}"),
               "the robot never pulls a part the chuck still clamps"),
        forbid("raw_part_to_outfeed", moving_to[AT_OUTFEED] & raw_in_gripper,
               "a raw part never goes to the outfeed"),
        forbid("finished_part_back_into_machine",
               any_of(moving_to[IN_CNC], all_of("cnc.clamp_c", f"ur.pos_m == {IN_CNC}")) & finished_in_gripper,
               "a finished part is never put back into the chuck"),
        forbid("part_left_gripped_on_outfeed",
               all_of("gripper.part_m", f"ur.pos_m == {AT_OUTFEED}", f"ur.ref_pos_c != {AT_OUTFEED}"),
               "the robot lets go of the part it set on the outfeed before it leaves"),
    )

