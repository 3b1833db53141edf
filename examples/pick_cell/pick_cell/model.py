"""A pick-and-place cell: a feeder presents boxes one at a time, a UR robot with a vacuum cup sets them on a pallet.

The story of each box k (`BOXES`), one planning operation per step:

1. `FeedBox<k>`: the feeder pushes box k to its pick position (only while the robot is
   out of the pick zone).
2. `PickBox<k>`: the robot goes down to the box, switches the suction on and holds the box
   once the vacuum builds; the feeder's sensor sees the box leave.
3. `PlaceBox<k>`: the robot carries the box to its pallet slot k and releases it there.

then `RobotHome`. The next box is fed while the robot places the last one.

The two device types of this cell are its own, defined here with the public modelling API
(`ability`/`Phase`, as in common/resources):

* `vacuum_ejector`: a compact vacuum ejector on the robot's flange, reached over Modbus TCP.
  It has a real driver (`pick_cell.driver`) and a protocol simulator (`pick_cell.sim`),
  registered as entry points of this package, so `--mode sim` runs it against the simulator.
* `box_feeder`: statehub knows no driver for it; it runs in `emulate` mode from this model.

Global estimated state lives under `cell.`: `cell.box<k>_e` follows each box through
`BOX_STAGES`, recorded by tracking abilities from what the sensors show.
"""

from __future__ import annotations

from common.model import (
    Ability,
    Domain,
    Model,
    Operation,
    Phase,
    Predicate,
    Resource,
    Specification,
    ability,
    all_of,
    any_of,
    command,
    estimated,
    forbid,
    measured,
    operation,
    tracking,
)
from common.resources import ur

EJECTOR_TYPE = "vacuum_ejector"
FEEDER_TYPE = "box_feeder"


def vacuum_ejector(name: str, robot: str, picks: dict[str, object]) -> Resource:
    """A vacuum ejector and its suction cup on `robot`; `picks[pose]` says when a box stands there to be picked.

    | ability | predicate               | control actions             | effects                      |
    |---------|-------------------------|-----------------------------|------------------------------|
    | suck    | !suction_c && !vacuum_m | suction_c := T (deliberate) | -                            |
    |         | suction_c && !vacuum_m  | -                           | vacuum_m := T (cup sealed)   |
    | release | suction_c && vacuum_m   | suction_c := F (deliberate) | -                            |
    |         | !suction_c && vacuum_m  | -                           | vacuum_m := F (blown off)    |

    `vacuum_m` is the ejector's switch point: the vacuum is above its hold threshold. The
    device cannot tell a box from no box (on a real cup the vacuum would not build on
    nothing), so the controller switches suction on only where a box stands: the guard.
    """
    suction_c = command(f"{name}.suction_c", initial=False, description="the suction valve is open")
    vacuum_m = measured(f"{name}.vacuum_m", description="the vacuum is above the hold threshold (switch point 1)")
    at_a_box = any_of(*(all_of(f"{robot}.pos_m == {pose}", ready) for pose, ready in picks.items()))
    suck = ability(
        f"{name}.suck",
        enabled=Phase(~suction_c & ~vacuum_m, deliberate=f"{suction_c.path} := true", guard=at_a_box),
        executing=Phase(suction_c & ~vacuum_m, effects=[f"{vacuum_m.path} := true"]),
        finished=suction_c & vacuum_m,
    )
    release = ability(
        f"{name}.release",
        enabled=Phase(suction_c & vacuum_m, deliberate=f"{suction_c.path} := false"),
        starting=Phase(~suction_c & vacuum_m, effects=[f"{vacuum_m.path} := false"]),
        finished=~suction_c & ~vacuum_m,
    )
    # Losing the command must not drop the box: the suction stays as it is.
    return Resource(name, (suction_c, vacuum_m), (suck, release), device_type=EJECTOR_TYPE,
                    parameters={"robot": robot, "emulated_delay": 0.2, "safe_state": {}})


def box_feeder(name: str, robot: str, ejector: str, pick_pose: str) -> Resource:
    """A feeder that pushes one box at a time to its pick position, where `robot` picks it at `pick_pose`.

    | ability | predicate                  | control actions          | effects          |
    |---------|----------------------------|--------------------------|------------------|
    | feed    | !feed_c && !box_m          | feed_c := T (deliberate) | -                |
    |         | feed_c && !box_m           | -                        | box_m := T       |
    |         | feed_c && box_m            | feed_c := F (automatic)  | -                |
    | taken   | box_m, held by the ejector | -                        | box_m := F       |
    """
    feed_c = command(f"{name}.feed_c", initial=False, description="push the next box out")
    box_m = measured(f"{name}.box_m", description="a box stands at the pick position")
    feed = ability(
        f"{name}.feed",
        enabled=Phase(~feed_c & ~box_m, deliberate=f"{feed_c.path} := true"),
        executing=Phase(feed_c & ~box_m, effects=[f"{box_m.path} := true"]),
        finished=Phase(feed_c & box_m, automatic=f"{feed_c.path} := false"),
    )
    # The sensor counts the box as gone once the cup holds it.
    held_there = all_of(f"{robot}.pos_m == {pick_pose}", f"{ejector}.vacuum_m")
    taken = ability(f"{name}.taken", executing=Phase(box_m & held_there, effects=[f"{box_m.path} := false"]),
                    finished=~box_m)
    return Resource(name, (feed_c, box_m), (feed, taken), device_type=FEEDER_TYPE,
                    parameters={"robot": robot, "ejector": ejector, "pose": pick_pose, "emulated_delay": 0.4,
                                "safe_state": {"feed_c": False}})


# --- the cell --------------------------------------------------------------------------
BOX_COUNT = 3
BOXES = tuple(range(1, BOX_COUNT + 1))
BOX_STAGES = Domain.enum("waiting", "at_pick", "held", "placed")

HOME, ABOVE_FEEDER, AT_FEEDER, ABOVE_PALLET = "home", "above_feeder", "at_feeder", "above_pallet"
SLOTS = tuple(f"slot{k}" for k in BOXES)
POSES = (HOME, ABOVE_FEEDER, AT_FEEDER, ABOVE_PALLET, *SLOTS)
# The pick position and each pallet slot are reached only from their approach poses.
ALLOWED_MOVES = (
    (HOME, ABOVE_FEEDER), (ABOVE_FEEDER, AT_FEEDER),
    (HOME, ABOVE_PALLET), (ABOVE_FEEDER, ABOVE_PALLET),
    *((ABOVE_PALLET, slot) for slot in SLOTS),
)


def box(k: int) -> str:
    return f"cell.box{k}_e"


def build_model() -> Model:
    resources = (
        ur("ur", POSES, ALLOWED_MOVES, HOME),
        vacuum_ejector("vac", "ur", {AT_FEEDER: "feeder.box_m"}),
        box_feeder("feeder", "ur", "vac", AT_FEEDER),
    )
    boxes = tuple(estimated(box(k), BOX_STAGES, "waiting", f"box {k}") for k in BOXES)
    return Model("pick_cell", resources, boxes, _tracking(), _operations(), _specifications())


def _tracking() -> tuple[Ability, ...]:
    abilities: list[Ability] = []
    for k, slot in zip(BOXES, SLOTS, strict=True):
        # Boxes come in order: box k is the one that arrives once every earlier box has.
        arrives = all_of(f"{box(k)} == waiting", "feeder.box_m", *(f"{box(j)} != waiting" for j in BOXES if j < k),
                         *(f"{box(j)} != at_pick" for j in BOXES if j != k))
        steps = (
            ("arrived", arrives, "at_pick"),
            ("held", all_of(f"{box(k)} == at_pick", "vac.vacuum_m", "!feeder.box_m"), "held"),
            ("placed", all_of(f"{box(k)} == held", "!vac.vacuum_m", f"ur.pos_m == {slot}"), "placed"),
        )
        abilities += [tracking(f"cell.box{k}_{name}", guard, f"{box(k)} := {stage}") for name, guard, stage in steps]
    return tuple(abilities)


def _stage_in(k: int, *stages: str) -> Predicate:
    return any_of(*(f"{box(k)} == {s}" for s in stages))


def _operations() -> tuple[Operation, ...]:
    operations: list[Operation] = []
    for k in BOXES:
        # One box at the pick position at a time: box k is fed once box k-1 left it.
        previous_gone = _stage_in(k - 1, "held", "placed") if k > 1 else True
        operations += [
            operation(f"FeedBox{k}", all_of(f"{box(k)} == waiting", previous_gone), f"{box(k)} == at_pick",
                      description=f"the feeder pushes box {k} to the pick position"),
            operation(f"PickBox{k}", f"{box(k)} == at_pick", f"{box(k)} == held",
                      description=f"the robot picks box {k} with the suction cup"),
            operation(f"PlaceBox{k}", f"{box(k)} == held", f"{box(k)} == placed",
                      description=f"the robot sets box {k} on pallet slot {k}"),
        ]
    operations.append(operation("RobotHome", all_of(*(f"{box(k)} == placed" for k in BOXES)),
                                f"ur.pos_m == {HOME} && !vac.suction_c",
                                description="the robot goes home with the suction off"))
    return tuple(operations)


def _specifications() -> tuple[Specification, ...]:
    # Between poses only the target is known: every move to the approach pose counts as in the zone.
    in_pick_zone = any_of(f"ur.pos_m == {AT_FEEDER}", f"ur.ref_pos_c == {AT_FEEDER}",
                          all_of(f"ur.ref_pos_c == {ABOVE_FEEDER}", "ur.pos_m == unknown"))
    over_own_slot = any_of(*(all_of(f"ur.pos_m == {slot}", f"{box(k)} == held") for k, slot in zip(BOXES, SLOTS,
                                                                                                     strict=True)))
    return (
        forbid("feeder_pushes_with_robot_at_pick", all_of("feeder.feed_c") & in_pick_zone,
               "the feeder never pushes a box while the robot is in its pick zone"),
        forbid("box_dropped", all_of("!vac.suction_c", "vac.vacuum_m") & ~over_own_slot,
               "the suction lets go of a box only over that box's pallet slot"),
        forbid("box_carried_into_pick", all_of("vac.vacuum_m", f"ur.ref_pos_c == {AT_FEEDER}",
                                               f"ur.pos_m != {AT_FEEDER}"),
               "the robot never brings a box down to the pick position"),
    )
