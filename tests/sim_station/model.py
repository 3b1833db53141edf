"""A small engine-assembly station for the sim-mode tests: the reference story, with 2 bolts, 1 filter, 1 pipe.

Same resources, same kinds of operations, tracking and specifications as
`common.stations.engine_assembly` (read that module for the story), only fewer of
them, so that a whole run with every device against its simulator stays short:

* every driver type takes part: the nutrunner tightens bolts on the robot and a pipe
  plate in the operator's hand (the dock sees it taken out of its slot), the robot
  moves between named poses, the tool changer couples all three tools from the dock,
  the lift carries the ladder frame, the MiR and the AGV come and go, the operator
  badges in at the RFID reader and the camera sees the operator in the shared zone and,
  for the pipe, in the robot zone;
* the operator's confirmations wait for what the operator sees (the frame seated, the
  plate tightened), which the operator's hub reads from the controller's state.
"""

from __future__ import annotations

from common.model import (
    Ability,
    In,
    Model,
    Operation,
    Predicate,
    Specification,
    all_of,
    any_of,
    forbid,
    operation,
    operation_running,
    tracking,
)
from common.model import estimated as estimated_var
from common.resources import agv, camera, dock, lift, mir, nutrunner, operator, rfid, rsp, ur
from common.resources.rsp import TOOLS, default_dock_poses
from common.resources.ur import neighbours
from common.stations.engine_assembly import BOLT_STATES, FILTER_STATES, FRAME_STATES, PIPE_STATES

BOLTS = (1, 2)
FRAME = "engine.frame_e"
BOLT_POSES = tuple(f"at_bolt{i}" for i in BOLTS)
DOCK_POSES = default_dock_poses()
POSES = ("home", *DOCK_POSES.values(), "at_frame", "above_engine", *BOLT_POSES, "at_filter1")
SHARED_POSES = ("at_frame", "above_engine", *BOLT_POSES, "at_filter1")
ALLOWED_MOVES = (
    *(("home", p) for p in DOCK_POSES.values()),
    ("home", "at_frame"), ("home", "above_engine"), ("at_frame", "above_engine"),
    *(("above_engine", p) for p in BOLT_POSES), (BOLT_POSES[0], BOLT_POSES[1]),
    ("above_engine", "at_filter1"),
)
TASKS = ("lift_frame", "place_bolts", "mount_filter1", "mount_oil_pipes", "tighten_pipe1")
TASK_ZONES = {task: "shared" for task in TASKS} | {"tighten_pipe1": "robot"}
OPERATOR_OPERATIONS = ("LiftLadderFrame", "PlaceBolts", "MountFilter1", "MountOilPipes", "TightenPipe1")


def bolt(i: int) -> str:
    return f"engine.bolt{i}_e"


def build_model() -> Model:
    resources = (
        agv(), mir(), rfid(),
        operator("human", TASKS,
                 confirm_when={"lift_frame": all_of(f"{FRAME} == lifted", "ur.pos_m == above_engine",
                                                    "lift.pos_m == down"),
                               "place_bolts": f"{FRAME} == placed",
                               "tighten_pipe1": "engine.pipe1_e == tightened"},
                 on_confirm={"lift_frame": [f"{FRAME} := placed"],
                             "place_bolts": [f"{bolt(i)} := placed" for i in BOLTS],
                             "mount_filter1": ["engine.filter1_e := mounted"],
                             "mount_oil_pipes": ["engine.pipe1_e := mounted"]}),
        camera("cam", "human", TASK_ZONES),
        ur("ur", POSES, ALLOWED_MOVES, "home"),
        rsp("rsp", "ur", "dock", DOCK_POSES),
        dock("dock", "ur", "rsp", DOCK_POSES, "human", {"nutrunner": ("tighten_pipe1",)}),
        nutrunner("nr"),
        lift("lift"),
    )
    variables = (
        estimated_var(FRAME, FRAME_STATES, "on_kit", "the ladder frame"),
        *(estimated_var(bolt(i), BOLT_STATES, "absent", f"frame bolt {i}") for i in BOLTS),
        estimated_var("engine.filter1_e", FILTER_STATES, "absent", "oil filter 1"),
        estimated_var("engine.pipe1_e", PIPE_STATES, "absent", "oil pipe 1 and its plate"),
    )
    return Model("sim_station", resources, variables, _tracking(), _operations(), _specifications())


def _tracking() -> tuple[Ability, ...]:
    return (
        tracking("engine.frame_lifted",
                 all_of(f"{FRAME} == on_kit", "ur.pos_m == at_frame", "rsp.tool_m == lift_tool", "lift.pos_m == up",
                        "human.instr_c == lift_frame"),
                 f"{FRAME} := lifted"),
        *(tracking(f"engine.bolt{i}_tightened",
                   all_of(f"{bolt(i)} == placed", "nr.tqr_m", "rsp.tool_m == nutrunner", f"ur.pos_m == at_bolt{i}"),
                   f"{bolt(i)} := tightened") for i in BOLTS),
        tracking("engine.filter1_tightened",
                 all_of("engine.filter1_e == mounted", "rsp.tool_m == filter_tool", "ur.pos_m == at_filter1"),
                 "engine.filter1_e := tightened"),
        tracking("engine.pipe1_tightened",
                 all_of("engine.pipe1_e == mounted", "nr.tqr_m", "human.instr_c == tighten_pipe1",
                        "!dock.nutrunner_home_m", "rsp.tool_m != nutrunner"),
                 "engine.pipe1_e := tightened"),
    )


# The operations run one after the other (each waits for the one before to finish), so that
# the planner only ever plans for one or two goals: these tests are about the devices.
SEQUENCE = (
    ("AgvArrive", "MirArrive", "VerifyOperator"), ("AttachLiftTool",), ("LiftLadderFrame",), ("PlaceBolts",),
    ("AttachNutrunner",), *((f"TightenBolt{i}",) for i in BOLTS), ("ParkNutrunner",), ("MountFilter1",),
    ("AttachFilterTool",), ("TightenFilter1",), ("MountOilPipes",), ("TightenPipe1",), ("RobotHome",),
    ("AgvLeave", "MirLeave"),
)


def _after(name: str) -> Predicate | bool:
    """`op.X == finished` for every operation of the step before `name`'s."""
    step = next(i for i, names in enumerate(SEQUENCE) if name in names)
    return all_of(*(f"op.{prev} == finished" for prev in SEQUENCE[step - 1])) if step else True


def _operations() -> tuple[Operation, ...]:
    frame_placed = f"{FRAME} == placed"
    bolts_placed = all_of(*(f"{bolt(i)} != absent" for i in BOLTS))
    bolts_tightened = all_of(*(f"{bolt(i)} == tightened" for i in BOLTS))
    all_tightened = all_of(bolts_tightened, "engine.filter1_e == tightened", "engine.pipe1_e == tightened")
    operations = (
        operation("AgvArrive", "agv.pos_m == away && agv.engine_m", "agv.pos_m == at_station"),
        operation("MirArrive", "mir.pos_m == at_kitting", "mir.pos_m == at_station"),
        operation("VerifyOperator", True, "rfid.verified_m"),
        operation("AttachLiftTool", "rsp.tool_m == none && dock.lift_tool_home_m", "rsp.tool_m == lift_tool"),
        operation("LiftLadderFrame", all_of("agv.pos_m == at_station", "mir.pos_m == at_station",
                                            f"{FRAME} == on_kit"), frame_placed),
        operation("PlaceBolts", all_of(frame_placed, *(f"{bolt(i)} == absent" for i in BOLTS)), bolts_placed),
        operation("AttachNutrunner", frame_placed, "rsp.tool_m == nutrunner"),
        *(operation(f"TightenBolt{i}", all_of(frame_placed, f"{bolt(i)} == placed"), f"{bolt(i)} == tightened")
          for i in BOLTS),
        operation("ParkNutrunner", bolts_tightened, "ur.pos_m == above_engine"),
        operation("MountFilter1", all_of(bolts_placed, "engine.filter1_e == absent"), "engine.filter1_e != absent"),
        operation("AttachFilterTool", all_of(bolts_tightened, "engine.filter1_e != absent"),
                  "rsp.tool_m == filter_tool"),
        operation("TightenFilter1", all_of(bolts_tightened, "engine.filter1_e == mounted"),
                  "engine.filter1_e == tightened"),
        operation("MountOilPipes", all_of("engine.filter1_e != absent", "engine.pipe1_e == absent"),
                  "engine.pipe1_e != absent"),
        operation("TightenPipe1", all_of(bolts_tightened, "engine.pipe1_e == mounted"), "engine.pipe1_e == tightened"),
        operation("RobotHome", all_of(bolts_tightened, "engine.filter1_e == tightened"),
                  "ur.pos_m == home && rsp.tool_m == none"),
        operation("AgvLeave", all_of(all_tightened, "ur.pos_m == home"), "agv.pos_m == away"),
        operation("MirLeave", all_of(all_tightened, "ur.pos_m == home"), "mir.pos_m == at_kitting"),
    )
    return tuple(operation(op.name, all_of(op.pre, _after(op.name)), op.goal) for op in operations)


def _specifications() -> tuple[Specification, ...]:
    graph = neighbours(POSES, ALLOWED_MOVES)
    shared_targets = tuple(p for p in POSES if p in SHARED_POSES or set(graph[p]) & set(SHARED_POSES))
    moving_in_shared_zone = any_of(*(all_of(f"ur.ref_pos_c == {p}", f"ur.pos_m != {p}") for p in shared_targets))
    unverified = all_of("!rfid.verified_m")
    return (
        forbid("robot_moves_in_shared_zone_while_operator_sent_to_robot_zone",
               In("human.instr_c", ("tighten_pipe1",)) & moving_in_shared_zone),
        forbid("robot_moves_in_shared_zone_while_operator_seen_in_robot_zone",
               all_of("cam.zone_m == robot") & moving_in_shared_zone),
        forbid("operator_instructed_before_verified", unverified & all_of("human.instr_c != none")),
        forbid("operator_operation_before_verified",
               unverified & any_of(*(operation_running(name) for name in OPERATOR_OPERATIONS))),
        forbid("tool_released_outside_its_slot",
               any_of(*(all_of("!rsp.lock_c", f"rsp.tool_m == {tool}", f"ur.pos_m != {DOCK_POSES[tool]}")
                        for tool in TOOLS))),
        forbid("robot_moves_while_its_nutrunner_runs", "nr.run_m && rsp.tool_m == nutrunner && ur.pos_m == unknown"),
    )
