"""The reference station: collaborative assembly of a truck engine (the paper's demonstrator).

The story, one planning operation per step (`OPERATION_ORDER`):

1. The AGV brings the engine and the MiR the kitted material; the operator is verified
   by RFID.
2. The robot takes the lift tool. Robot (with the lifting system carrying the weight)
   and operator lift the ladder frame from the kit onto the engine; the operator
   confirms it is seated.
3. The robot leaves the lift tool in the dock and takes the nutrunner while the
   operator places the 24 bolts; the robot tightens them, one operation per bolt,
   while the operator mounts the 3 oil filters. If the robot finishes first it parks
   the nutrunner above the engine and waits.
4. The robot changes to the oil-filter tool and tightens the filters. The operator
   mounts the two oil pipes and tightens their plates with the same nutrunner, taken
   by hand from its dock slot.
5. The robot docks its tool and goes home; the AGV and the MiR leave.

Variants (an order asks for one; DESIGN.md §12): `full` is the story above; `light` is an engine
with 20 bolts, 2 filters and no oil pipes, so its orders leave out TightenBolt21-24, MountFilter3,
TightenFilter3, MountOilPipes and TightenPipe1-2. The variant's parameters `engine.count_bolts_e`,
`engine.count_filters_e` and `engine.count_pipes_e` say how many of each the engine takes; the operations that
wait for every part (ParkNutrunner, AttachFilterTool, RobotHome, AgvLeave, ...) wait only for the
parts the engine takes, so that one model serves both. (The operator's confirmation of PlaceBolts
still marks all 24 bolts placed: the operator model's confirmations are fixed actions.)

Global estimated state lives under `engine.`: `engine.frame_e`, `engine.bolt<i>_e`,
`engine.filter<k>_e`, `engine.pipe<k>_e`. Tracking abilities set it from
measurements (a bolt is tightened when the nutrunner reports torque while the robot
holding it is at that bolt); the operator's confirmations record what only the
operator can see (placed bolts, mounted filters).

Safety is stated as forbidden states (`specifications`), over the controllable
quantities where possible: in the model the camera's zone follows the operator's
instruction, so "the operator is in the robot zone" is `human.instr_c in
ROBOT_ZONE_TASKS`; the camera form of the same rule is kept as well, as the run-time
guard that waits for the camera to see the operator leave.
"""

from __future__ import annotations

from itertools import pairwise

from common.model import (
    Ability,
    Domain,
    In,
    Model,
    Operation,
    Predicate,
    Specification,
    Variable,
    Variant,
    all_of,
    any_of,
    estimated,
    forbid,
    operation,
    operation_running,
    tracking,
    variant,
)
from common.resources import agv, camera, dock, lift, mir, nutrunner, operator, rfid, rsp, ur
from common.resources.rsp import TOOLS, default_dock_poses
from common.resources.ur import neighbours

# --- the product -------------------------------------------------------------------
BOLT_COUNT = 24
FILTER_COUNT = 3
PIPE_COUNT = 2
BOLTS = tuple(range(1, BOLT_COUNT + 1))
FILTERS = tuple(range(1, FILTER_COUNT + 1))
PIPES = tuple(range(1, PIPE_COUNT + 1))

FRAME_STATES = Domain.enum("on_kit", "lifted", "placed")
BOLT_STATES = Domain.enum("absent", "placed", "tightened")
FILTER_STATES = Domain.enum("absent", "mounted", "tightened")
PIPE_STATES = Domain.enum("absent", "mounted", "tightened")  # a pipe is tightened when its plate is

FRAME = "engine.frame_e"

# How many bolts, filters and pipes this engine takes: its variant's parameters, set when its order
# starts and constant through the order. The fewest any variant takes are always required.
BOLTS_TAKEN = "engine.count_bolts_e"
FILTERS_TAKEN = "engine.count_filters_e"
PIPES_TAKEN = "engine.count_pipes_e"
FEWEST_BOLTS, FEWEST_FILTERS, FEWEST_PIPES = 20, 2, 0


def bolt(i: int) -> str:
    return f"engine.bolt{i}_e"


def oil_filter(k: int) -> str:
    return f"engine.filter{k}_e"


def pipe(k: int) -> str:
    return f"engine.pipe{k}_e"


# --- the robot's poses -------------------------------------------------------------
HOME = "home"
ABOVE_ENGINE = "above_engine"
AT_FRAME = "at_frame"  # the ladder frame on the MiR's kit
DOCK_POSES = default_dock_poses()
BOLT_POSES = tuple(f"at_bolt{i}" for i in BOLTS)
FILTER_POSES = tuple(f"at_filter{k}" for k in FILTERS)
POSES = (HOME, *DOCK_POSES.values(), AT_FRAME, ABOVE_ENGINE, *BOLT_POSES, *FILTER_POSES)
# The collaborative area around the engine, where robot and operator work together.
SHARED_POSES = (AT_FRAME, ABOVE_ENGINE, *BOLT_POSES, *FILTER_POSES)


def _ring(poses: tuple[str, ...]) -> list[tuple[str, str]]:
    return [(poses[i], poses[(i + 1) % len(poses)]) for i in range(len(poses))]


# The bolts form a ring around `above_engine` and each is also reachable straight from
# it: a single bolt is two moves away, and all 24 make one tour around the ring.
ALLOWED_MOVES: tuple[tuple[str, str], ...] = (
    *((HOME, dock_pose) for dock_pose in DOCK_POSES.values()),
    (HOME, AT_FRAME),
    (HOME, ABOVE_ENGINE),
    (AT_FRAME, ABOVE_ENGINE),
    *((ABOVE_ENGINE, p) for p in BOLT_POSES),
    *_ring(BOLT_POSES),
    *((ABOVE_ENGINE, p) for p in FILTER_POSES),
    *pairwise(FILTER_POSES),
)

# --- the operator ------------------------------------------------------------------
LIFT_FRAME = "lift_frame"
PLACE_BOLTS = "place_bolts"
MOUNT_OIL_PIPES = "mount_oil_pipes"
MOUNT_FILTER_TASKS = tuple(f"mount_filter{k}" for k in FILTERS)
TIGHTEN_PIPE_TASKS = tuple(f"tighten_pipe{k}" for k in PIPES)
OPERATOR_TASKS = (LIFT_FRAME, PLACE_BOLTS, *MOUNT_FILTER_TASKS, MOUNT_OIL_PIPES, *TIGHTEN_PIPE_TASKS)
# Tightening a pipe plate the operator fetches the nutrunner from the dock and works on the
# robot's side of the engine: the robot zone. Everything else is done in the shared zone.
TASK_ZONES = {task: "shared" for task in OPERATOR_TASKS} | {task: "robot" for task in TIGHTEN_PIPE_TASKS}
ROBOT_ZONE_TASKS = tuple(task for task, zone in TASK_ZONES.items() if zone == "robot")

# --- the operations ----------------------------------------------------------------
OPERATION_ORDER = (
    "AgvArrive", "MirArrive", "VerifyOperator",
    "AttachLiftTool", "LiftLadderFrame",
    "AttachNutrunner", "PlaceBolts", *(f"TightenBolt{i}" for i in BOLTS), "ParkNutrunner",
    *(f"MountFilter{k}" for k in FILTERS),
    "AttachFilterTool", *(f"TightenFilter{k}" for k in FILTERS),
    "MountOilPipes", *(f"TightenPipe{k}" for k in PIPES),
    "RobotHome", "AgvLeave", "MirLeave",
)
# Operations the operator takes part in: none of them may run before the operator is verified.
OPERATOR_OPERATIONS = (
    "LiftLadderFrame", "PlaceBolts", *(f"MountFilter{k}" for k in FILTERS),
    "MountOilPipes", *(f"TightenPipe{k}" for k in PIPES),
)


def build_model() -> Model:
    resources = (
        agv(),
        mir(),
        rfid(),
        operator("human", OPERATOR_TASKS, confirm_when=_operator_can_confirm(), on_confirm=_operator_confirms()),
        camera("cam", "human", TASK_ZONES),
        ur("ur", POSES, ALLOWED_MOVES, HOME),
        rsp("rsp", "ur", "dock", DOCK_POSES),
        dock("dock", "ur", "rsp", DOCK_POSES, "human", {"nutrunner": TIGHTEN_PIPE_TASKS}),
        nutrunner("nr"),
        lift("lift"),
    )
    return Model("engine_assembly", resources, _engine_variables(), _tracking(), _operations(), _specifications(),
                 product=("engine.*",), variants=_variants())


def _variants() -> tuple[Variant, ...]:
    light_leaves_out = {
        *(f"TightenBolt{i}" for i in BOLTS if i > FEWEST_BOLTS),
        *(f"MountFilter{k}" for k in FILTERS if k > FEWEST_FILTERS),
        *(f"TightenFilter{k}" for k in FILTERS if k > FEWEST_FILTERS),
        "MountOilPipes", *(f"TightenPipe{k}" for k in PIPES),
    }
    return (
        variant("full", parameters={BOLTS_TAKEN: BOLT_COUNT, FILTERS_TAKEN: FILTER_COUNT, PIPES_TAKEN: PIPE_COUNT},
                description=f"{BOLT_COUNT} bolts, {FILTER_COUNT} oil filters, {PIPE_COUNT} oil pipes"),
        variant("light", [name for name in OPERATION_ORDER if name not in light_leaves_out],
                {BOLTS_TAKEN: FEWEST_BOLTS, FILTERS_TAKEN: FEWEST_FILTERS, PIPES_TAKEN: FEWEST_PIPES},
                description=f"{FEWEST_BOLTS} bolts, {FEWEST_FILTERS} oil filters, no oil pipes"),
    )


def _engine_variables() -> tuple[Variable, ...]:
    return (
        estimated(FRAME, FRAME_STATES, "on_kit", "the ladder frame"),
        *(estimated(bolt(i), BOLT_STATES, "absent", f"frame bolt {i}") for i in BOLTS),
        *(estimated(oil_filter(k), FILTER_STATES, "absent", f"oil filter {k}") for k in FILTERS),
        *(estimated(pipe(k), PIPE_STATES, "absent", f"oil pipe {k} and its plate") for k in PIPES),
        # Last, so that the variables before them keep their places in the packed state.
        estimated(BOLTS_TAKEN, Domain.range(FEWEST_BOLTS, BOLT_COUNT), BOLT_COUNT, "frame bolts this engine takes"),
        estimated(FILTERS_TAKEN, Domain.range(FEWEST_FILTERS, FILTER_COUNT), FILTER_COUNT,
                  "oil filters this engine takes"),
        estimated(PIPES_TAKEN, Domain.range(FEWEST_PIPES, PIPE_COUNT), PIPE_COUNT, "oil pipes this engine takes"),
    )


def _operator_can_confirm() -> dict[str, object]:
    return {
        # The operator can only see the frame seated once it was lifted, carried over the
        # engine and lowered.
        LIFT_FRAME: all_of(f"{FRAME} == lifted", f"ur.pos_m == {ABOVE_ENGINE}", "lift.pos_m == down"),
        PLACE_BOLTS: f"{FRAME} == placed",
        **{task: f"{pipe(k)} == tightened" for k, task in zip(PIPES, TIGHTEN_PIPE_TASKS, strict=True)},
    }


def _operator_confirms() -> dict[str, list[str]]:
    return {
        LIFT_FRAME: [f"{FRAME} := placed"],
        PLACE_BOLTS: [f"{bolt(i)} := placed" for i in BOLTS],
        **{task: [f"{oil_filter(k)} := mounted"] for k, task in zip(FILTERS, MOUNT_FILTER_TASKS, strict=True)},
        MOUNT_OIL_PIPES: [f"{pipe(k)} := mounted" for k in PIPES],
    }


def _tracking() -> tuple[Ability, ...]:
    frame_lifted = tracking(
        "engine.frame_lifted",
        all_of(f"{FRAME} == on_kit", f"ur.pos_m == {AT_FRAME}", "rsp.tool_m == lift_tool", "lift.pos_m == up",
               f"human.instr_c == {LIFT_FRAME}"),
        f"{FRAME} := lifted",
    )
    bolts = tuple(
        tracking(f"engine.bolt{i}_tightened",
                 all_of(f"{bolt(i)} == placed", "nr.tqr_m", "rsp.tool_m == nutrunner", f"ur.pos_m == at_bolt{i}"),
                 f"{bolt(i)} := tightened")
        for i in BOLTS
    )
    # The filter tool is passive: the force-controlled move onto a filter screws it tight.
    filters = tuple(
        tracking(f"engine.filter{k}_tightened",
                 all_of(f"{oil_filter(k)} == mounted", "rsp.tool_m == filter_tool", f"ur.pos_m == at_filter{k}"),
                 f"{oil_filter(k)} := tightened")
        for k in FILTERS
    )
    # The operator holds the nutrunner: out of its slot, not on the robot, instructed to tighten pipe k.
    pipes = tuple(
        tracking(f"engine.pipe{k}_tightened",
                 all_of(f"{pipe(k)} == mounted", "nr.tqr_m", f"human.instr_c == {task}",
                        "!dock.nutrunner_home_m", "rsp.tool_m != nutrunner"),
                 f"{pipe(k)} := tightened")
        for k, task in zip(PIPES, TIGHTEN_PIPE_TASKS, strict=True)
    )
    return (frame_lifted, *bolts, *filters, *pipes)


def _every(paths: tuple[str, ...], condition: str) -> Predicate:
    return all_of(*(f"{path} {condition}" for path in paths))


def _every_taken(paths: tuple[str, ...], condition: str, taken: str, fewest: int) -> Predicate:
    """`condition` of each part the engine takes: the first `fewest` always, part n once `taken` >= n."""
    return all_of(*(f"{path} {condition}" if n <= fewest
                    else any_of(f"{path} {condition}", In(taken, tuple(range(fewest, n))))
                    for n, path in enumerate(paths, start=1)))


def _operations() -> tuple[Operation, ...]:
    bolts, filters, pipes = tuple(map(bolt, BOLTS)), tuple(map(oil_filter, FILTERS)), tuple(map(pipe, PIPES))
    frame_placed = f"{FRAME} == placed"
    bolts_placed = _every(bolts, "!= absent")
    bolts_tightened = _every_taken(bolts, "== tightened", BOLTS_TAKEN, FEWEST_BOLTS)
    filters_mounted = _every_taken(filters, "!= absent", FILTERS_TAKEN, FEWEST_FILTERS)
    filters_tightened = _every_taken(filters, "== tightened", FILTERS_TAKEN, FEWEST_FILTERS)
    all_tightened = all_of(bolts_tightened, filters_tightened, _every_taken(pipes, "== tightened", PIPES_TAKEN,
                                                                             FEWEST_PIPES))
    operations = [
        operation("AgvArrive", "agv.pos_m == away && agv.engine_m", "agv.pos_m == at_station",
                  description="the AGV brings the engine"),
        operation("MirArrive", "mir.pos_m == at_kitting", "mir.pos_m == at_station",
                  description="the MiR brings the kitted material"),
        operation("VerifyOperator", True, "rfid.verified_m", description="the operator scans a badge"),
        operation("AttachLiftTool", "rsp.tool_m == none && dock.lift_tool_home_m", "rsp.tool_m == lift_tool",
                  description="the robot takes the lift tool"),
        operation("LiftLadderFrame",
                  all_of("agv.pos_m == at_station", "mir.pos_m == at_station", f"{FRAME} == on_kit"),
                  frame_placed, description="robot, lifting system and operator lift the ladder frame onto the engine"),
        operation("AttachNutrunner", frame_placed, "rsp.tool_m == nutrunner",
                  description="the robot docks the lift tool and takes the nutrunner"),
        operation("PlaceBolts", all_of(frame_placed, _every(bolts, "== absent")), bolts_placed,
                  description="the operator places the 24 bolts"),
        *(operation(f"TightenBolt{i}", all_of(frame_placed, f"{bolt(i)} == placed"), f"{bolt(i)} == tightened",
                    description=f"the robot tightens bolt {i}") for i in BOLTS),
        operation("ParkNutrunner", bolts_tightened, f"ur.pos_m == {ABOVE_ENGINE}",
                  description="the robot, done first, waits above the engine with the nutrunner"),
        *(operation(f"MountFilter{k}", all_of(bolts_placed, f"{oil_filter(k)} == absent"),
                    f"{oil_filter(k)} != absent", description=f"the operator mounts oil filter {k}")
          for k in FILTERS),
        operation("AttachFilterTool", all_of(bolts_tightened, filters_mounted), "rsp.tool_m == filter_tool",
                  description="the robot docks the nutrunner and takes the oil-filter tool"),
        *(operation(f"TightenFilter{k}", all_of(bolts_tightened, f"{oil_filter(k)} == mounted"),
                    f"{oil_filter(k)} == tightened", description=f"the robot tightens oil filter {k}")
          for k in FILTERS),
        operation("MountOilPipes", all_of(filters_mounted, _every(pipes, "== absent")), _every(pipes, "!= absent"),
                  description="the operator mounts the two oil pipes"),
        *(operation(f"TightenPipe{k}", all_of(bolts_tightened, f"{pipe(k)} == mounted"), f"{pipe(k)} == tightened",
                    description=f"the operator tightens the plate of oil pipe {k} with the nutrunner")
          for k in PIPES),
        operation("RobotHome", all_of(bolts_tightened, filters_tightened),
                  f"ur.pos_m == {HOME} && rsp.tool_m == none", description="the robot docks its tool and goes home"),
        operation("AgvLeave", all_of(all_tightened, f"ur.pos_m == {HOME}"), "agv.pos_m == away",
                  description="the AGV takes the engine away"),
        operation("MirLeave", all_of(all_tightened, f"ur.pos_m == {HOME}"), "mir.pos_m == at_kitting",
                  description="the MiR returns to kitting"),
    ]
    by_name = {op.name: op for op in operations}
    return tuple(by_name[name] for name in OPERATION_ORDER)


def _specifications() -> tuple[Specification, ...]:
    # A move is in the shared zone when it starts or ends at a shared pose. Once the robot is
    # between poses only its target is known, so every pose next to a shared one counts as a
    # shared target (conservative: `home`); then "ref_pos_c is such a target and the robot
    # is not there yet" covers each such move from the command to the arrival.
    graph = neighbours(POSES, ALLOWED_MOVES)
    shared_targets = tuple(p for p in POSES if p in SHARED_POSES or set(graph[p]) & set(SHARED_POSES))
    moving_in_shared_zone = any_of(*(all_of(f"ur.ref_pos_c == {p}", f"ur.pos_m != {p}") for p in shared_targets))
    unverified = all_of("!rfid.verified_m")
    operator_operation_active = any_of(*(operation_running(name) for name in OPERATOR_OPERATIONS))
    return (
        forbid("robot_moves_in_shared_zone_while_operator_sent_to_robot_zone",
               In("human.instr_c", ROBOT_ZONE_TASKS) & moving_in_shared_zone,
               "the robot never moves in the shared zone while the operator is in the robot zone"),
        forbid("robot_moves_in_shared_zone_while_operator_seen_in_robot_zone",
               all_of("cam.zone_m == robot") & moving_in_shared_zone,
               "the same, as the camera sees it: the robot waits for the operator to leave"),
        forbid("operator_instructed_before_verified", unverified & all_of("human.instr_c != none"),
               "without a verified operator the operator gets no instruction"),
        forbid("operator_operation_before_verified", unverified & operator_operation_active,
               "without a verified operator only robot-only operations run"),
        forbid("tool_released_outside_its_slot",
               any_of(*(all_of("!rsp.lock_c", f"rsp.tool_m == {tool}", f"ur.pos_m != {DOCK_POSES[tool]}")
                        for tool in TOOLS)),
               "the changer never lets go of a tool anywhere but in the tool's dock slot"),
        forbid("robot_moves_while_its_nutrunner_runs",
               "nr.run_m && rsp.tool_m == nutrunner && ur.pos_m == unknown",
               "the robot stands still while the nutrunner it holds is running"),
    )
