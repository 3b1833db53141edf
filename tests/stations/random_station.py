"""Random small stations from the standard device templates, for property tests of the whole controller.

`build_random_station(seed)` draws, from one `random.Random(seed)`:

* a UR robot (`ur`) with 2..5 work poses besides `home`, joined by a random tree of
  allowed moves plus a few shortcuts, holding a nutrunner (`nr`);
* 1..4 bolts, each at its own work pose (`cell.bolt<i>_e`, tracked as in the reference
  station: torque while the robot stands at the bolt), one `TightenBolt<i>` each;
* 0..2 inspection points (`Inspect<k>`: the robot visits a work pose, recorded in
  `cell.check<k>_e` as it arrives), which a bolt or a task may have to wait for;
* sometimes a tool changer and dock (`rsp`, `dock`): the robot first fetches the
  nutrunner from its slot (`AttachNutrunner`), and the changer never lets a tool go
  outside its slot;
* sometimes a human operator (`human`) with 1..2 tasks (`OperatorTask<t>`, recorded
  in `cell.task<t>_e` when confirmed), some after a given bolt, with a safety camera
  (`cam`) and an RFID badge check (`rfid`, `VerifyOperator`) now and then;
* random forbidden zones: work poses the robot may neither stand at nor move to while
  the operator is instructed into (or, with a camera, seen in) a zone;
* `RobotHome` once every bolt is tightened.

Every such station is valid and its specifications can be met from the initial state;
whether every operation is reachable is for the planner to say (`hubctl check`, or
`controller.planner.check_operations`). They are small: a plan takes milliseconds.
"""

from __future__ import annotations

import random

from common.model import (
    Domain,
    In,
    Model,
    Operation,
    Predicate,
    Resource,
    Specification,
    all_of,
    any_of,
    estimated,
    forbid,
    operation,
    tracking,
)
from common.resources import camera, dock, nutrunner, operator, rfid, rsp, ur
from common.resources.rsp import TOOLS, default_dock_poses

HOME = "home"
BOLT_STATES = Domain.enum("placed", "tightened")
TASK_STATES = Domain.enum("open", "done")


def bolt(i: int) -> str:
    return f"cell.bolt{i}_e"


def task(t: int) -> str:
    return f"cell.task{t}_e"


def check(k: int) -> str:
    return f"cell.check{k}_e"


def build_random_station(seed: int) -> Model:
    rng = random.Random(seed)
    work = tuple(f"p{k}" for k in range(1, rng.randint(2, 5) + 1))
    poses = (HOME, *work)
    # A random tree keeps every pose reachable; a few shortcuts make several routes.
    moves = [(poses[k], rng.choice(poses[:k])) for k in range(1, len(poses))]
    for _ in range(rng.randint(0, 2)):
        a, b = rng.sample(poses, 2)
        if (a, b) not in moves and (b, a) not in moves:
            moves.append((a, b))
    bolt_poses = rng.sample(work, rng.randint(1, min(4, len(work))))
    bolts = tuple(range(1, len(bolt_poses) + 1))
    check_poses = [rng.choice(work) for _ in range(rng.randint(0, 2))]
    checks = tuple(range(1, len(check_poses) + 1))
    # A record made as the robot arrives is the last thing that happens until the next command:
    # an operation waiting for it must start from that record alone.
    bolt_after = {i: rng.choice((None, None, *checks)) for i in bolts}

    with_changer = rng.random() < 0.25
    dock_poses = default_dock_poses()
    if with_changer:
        poses = (*poses, *dock_poses.values())
        moves += [(HOME, p) for p in dock_poses.values()]
    with_operator = rng.random() < 0.6
    tasks = tuple(f"task{t}" for t in range(1, rng.randint(1, 2) + 1)) if with_operator else ()
    task_zones = {name: rng.choice(("shared", "robot")) for name in tasks}
    with_camera = with_operator and rng.random() < 0.5
    with_rfid = with_operator and rng.random() < 0.3
    # A task may wait for a bolt or an inspection: the operator works on what the robot has done.
    task_after = {t: rng.choice((None, *((bolt(i), "tightened") for i in bolts), *((check(k), "done") for k in checks)))
                  for t in range(1, len(tasks) + 1)}

    resources: list[Resource] = [ur("ur", poses, moves, HOME), nutrunner("nr")]
    if with_changer:
        resources += [rsp("rsp", "ur", "dock", dock_poses), dock("dock", "ur", "rsp", dock_poses, "human")]
    if with_operator:
        records = {name: [f"{task(t)} := done"] for t, name in enumerate(tasks, start=1)}
        resources.append(operator("human", tasks, on_confirm=records))
    if with_camera:
        resources.append(camera("cam", "human", task_zones))
    if with_rfid:
        resources.append(rfid("rfid"))

    holds_nutrunner = ("rsp.tool_m == nutrunner",) if with_changer else ()
    variables = (
        *(estimated(bolt(i), BOLT_STATES, "placed", f"bolt {i}") for i in bolts),
        *(estimated(task(t), TASK_STATES, "open", f"operator task {t}") for t in range(1, len(tasks) + 1)),
        *(estimated(check(k), TASK_STATES, "open", f"inspection point {k}") for k in checks),
    )
    tracked = (
        *(tracking(f"cell.bolt{i}_tightened",
                   all_of(f"{bolt(i)} == placed", "nr.tqr_m", f"ur.pos_m == {pose}", *holds_nutrunner),
                   f"{bolt(i)} := tightened")
          for i, pose in zip(bolts, bolt_poses, strict=True)),
        *(tracking(f"cell.check{k}_inspected", all_of(f"{check(k)} == open", f"ur.pos_m == {pose}"),
                   f"{check(k)} := done")
          for k, pose in zip(checks, check_poses, strict=True)),
    )

    operations: list[Operation] = []
    if with_rfid:
        operations.append(operation("VerifyOperator", True, "rfid.verified_m"))
    if with_changer:
        operations.append(operation("AttachNutrunner", "rsp.tool_m == none", "rsp.tool_m == nutrunner"))
    operations += [operation(f"Inspect{k}", f"{check(k)} == open", f"{check(k)} == done") for k in checks]
    for i in bolts:
        after = bolt_after[i]
        pre = all_of(f"{bolt(i)} == placed", *((f"{check(after)} == done",) if after else ()))
        operations.append(operation(f"TightenBolt{i}", pre, f"{bolt(i)} == tightened"))
    for t in range(1, len(tasks) + 1):
        waits_for = task_after[t]
        pre = all_of(f"{task(t)} == open", *((f"{waits_for[0]} == {waits_for[1]}",) if waits_for else ()))
        operations.append(operation(f"OperatorTask{t}", pre, f"{task(t)} == done"))
    all_tightened = all_of(*(f"{bolt(i)} == tightened" for i in bolts))
    operations.append(operation("RobotHome", all_tightened, f"ur.pos_m == {HOME}"))

    specifications = [forbid("robot_moves_while_nutrunner_runs", "nr.run_m && ur.pos_m == unknown")]
    if with_changer:
        specifications.append(forbid(
            "tool_released_outside_its_slot",
            any_of(*(all_of("!rsp.lock_c", f"rsp.tool_m == {tool}", f"ur.pos_m != {dock_poses[tool]}")
                     for tool in TOOLS))))
    specifications += _zones(rng, work, tasks, task_zones, with_camera)
    if with_rfid:
        specifications.append(forbid("operator_instructed_before_verified",
                                     "!rfid.verified_m && human.instr_c != none"))
    return Model(f"random_{seed}", tuple(resources), variables, tracked, tuple(operations), tuple(specifications))


def _zones(rng: random.Random, work: tuple[str, ...], tasks: tuple[str, ...], task_zones: dict[str, str],
           with_camera: bool) -> list[Specification]:
    """For each zone the operator works in, a random set of work poses the robot keeps out of meanwhile."""
    specifications: list[Specification] = []
    for zone in sorted(set(task_zones.values())):
        if rng.random() < 0.3:
            continue  # a zone the robot may share with the operator
        poses = rng.sample(work, rng.randint(1, len(work)))
        robot_there = any_of(*(f"ur.pos_m == {p}" for p in poses), *(f"ur.ref_pos_c == {p}" for p in poses))
        instructed = In("human.instr_c", tuple(t for t in tasks if task_zones[t] == zone))
        specifications.append(forbid(f"robot_in_{zone}_zone_while_operator_sent_there", instructed & robot_there))
        if with_camera:
            moving: Predicate = any_of(*(all_of(f"ur.ref_pos_c == {p}", f"ur.pos_m != {p}") for p in poses))
            specifications.append(forbid(f"robot_moves_in_{zone}_zone_while_operator_seen_there",
                                         all_of(f"cam.zone_m == {zone}") & moving))
    return specifications
