"""The resource models: every factory builds a valid Model, follows the variable contract
(docs/resource-contract.md) and behaves as its device does, step by step."""

from __future__ import annotations

from collections.abc import Mapping

import pytest

from common.model import (
    Ability,
    Domain,
    Kind,
    Model,
    ModelError,
    Phase,
    Resource,
    TransitionKind,
    Value,
    ability,
    apply_all,
    command,
    estimated,
    measured,
    parse_predicate,
)
from common.resources import FACTORIES, agv, camera, dock, lift, mir, nutrunner, operator, rfid, rsp, ur
from common.resources.rsp import default_dock_poses

State = dict[str, Value]

TOOL_POSES = tuple(default_dock_poses().values())
ROBOT_POSES = ("home", *TOOL_POSES, "work")
ROBOT_MOVES = tuple(("home", p) for p in (*TOOL_POSES, "work"))


def robot_cell() -> Model:
    """A robot with its tool changer and dock, which read each other."""
    return Model("cell", (ur(poses=ROBOT_POSES, allowed_moves=ROBOT_MOVES), rsp(), dock()))


def fire(model: Model, state: State, name: str, outcome: int = 0) -> State:
    """Fire one transition by name (an effect takes the given outcome), then the automatic ones."""
    t = model.transition_by_name[name]
    assert t.guard.eval(state), f"{name} is not enabled in {state}: {t.guard}"
    return settle(model, apply_all(t.outcomes[outcome], state))


def settle(model: Model, state: State) -> State:
    for _ in range(100):
        enabled = [t for t in model.ability_transitions if t.kind is TransitionKind.AUTOMATIC and t.guard.eval(state)]
        if not enabled:
            return state
        state = apply_all(enabled[0].actions, state)
    raise AssertionError("automatic transitions do not settle")


def enabled(model: Model, state: Mapping[str, Value], kind: TransitionKind) -> set[str]:
    return {t.name for t in model.ability_transitions if t.kind is kind and t.guard.eval(state)}


# --- every factory, against the contract -------------------------------------------------
# short name -> (kind, domain values, initial); from docs/resource-contract.md
CONTRACT: dict[str, dict[str, tuple[Kind, tuple[Value, ...], Value | None]]] = {
    "nutrunner": {"run_c": (Kind.COMMAND, (False, True), False), "run_m": (Kind.MEASURED, (False, True), None),
                  "tqr_m": (Kind.MEASURED, (False, True), None), "fail_m": (Kind.MEASURED, (False, True), None)},
    "ur": {"ref_pos_c": (Kind.COMMAND, ROBOT_POSES, "home"),
           "pos_m": (Kind.MEASURED, (*ROBOT_POSES, "unknown"), None),
           "prot_stop_m": (Kind.MEASURED, (False, True), None)},
    "rsp": {"lock_c": (Kind.COMMAND, (False, True), False), "locked_m": (Kind.MEASURED, (False, True), None),
            "tool_m": (Kind.MEASURED, ("none", "nutrunner", "lift_tool", "filter_tool"), None),
            "pressure_ok_m": (Kind.MEASURED, (False, True), None)},
    "dock": {f"{tool}_home_m": (Kind.MEASURED, (False, True), None)
             for tool in ("nutrunner", "lift_tool", "filter_tool")},
    "lift": {"ref_c": (Kind.COMMAND, ("down", "up"), "down"),
             "pos_m": (Kind.MEASURED, ("down", "between", "up"), None)},
    "mir": {"goto_c": (Kind.COMMAND, ("none", "kitting", "station"), "none"),
            "pos_m": (Kind.MEASURED, ("at_kitting", "moving", "at_station"), None)},
    "agv": {"goto_c": (Kind.COMMAND, ("none", "station", "exit"), "none"),
            "pos_m": (Kind.MEASURED, ("away", "moving", "at_station"), None),
            "engine_m": (Kind.MEASURED, (False, True), None)},
    "rfid": {"verified_m": (Kind.MEASURED, (False, True), None)},
    "camera": {"zone_m": (Kind.MEASURED, ("outside", "shared", "robot"), None)},
    "operator": {"instr_c": (Kind.COMMAND, ("none", "fetch", "assemble"), "none"),
                 "done_m": (Kind.MEASURED, (False, True), None)},
}
DEFAULT_NAMES = {"nutrunner": "nr", "ur": "ur", "rsp": "rsp", "dock": "dock", "lift": "lift", "mir": "mir",
                 "agv": "agv", "rfid": "rfid", "camera": "cam", "operator": "human"}


def every_resource() -> dict[str, Resource]:
    return {
        "nutrunner": nutrunner(), "ur": ur(poses=ROBOT_POSES, allowed_moves=ROBOT_MOVES), "rsp": rsp(), "dock": dock(),
        "lift": lift(), "mir": mir(), "agv": agv(), "rfid": rfid(),
        "camera": camera(task_zones={"fetch": "robot", "assemble": "shared"}),
        "operator": operator(tasks=("fetch", "assemble")),
    }


def test_all_resources_build_one_valid_model() -> None:
    model = Model("everything", tuple(every_resource().values()))
    assert model.problems() == []


@pytest.mark.parametrize("device_type", sorted(FACTORIES))
def test_factory_builds_a_valid_model_with_defaults(device_type: str) -> None:
    resource = FACTORIES[device_type]()
    partners = {"rsp": (ur(poses=ROBOT_POSES, allowed_moves=ROBOT_MOVES), dock()),
                "dock": (ur(poses=ROBOT_POSES, allowed_moves=ROBOT_MOVES), rsp())}.get(device_type, ())
    model = Model(device_type, (resource, *partners))
    assert resource.device_type == device_type
    assert resource.name == DEFAULT_NAMES[device_type]
    assert model.problems() == []


@pytest.mark.parametrize("device_type", sorted(CONTRACT))
def test_variables_follow_the_contract(device_type: str) -> None:
    resource = every_resource()[device_type]
    expected = CONTRACT[device_type]
    assert {v.name for v in resource.variables} == set(expected)
    for short, (kind, values, initial) in expected.items():
        variable = resource.var(short)
        assert variable.kind is kind, short
        assert variable.domain.values == values, short
        if initial is not None:
            assert variable.initial == initial, short


@pytest.mark.parametrize("device_type", sorted(CONTRACT))
def test_phases_use_the_standard_names(device_type: str) -> None:
    standard = {"enabled", "starting", "executing", "finished", "resetting"}
    for a in every_resource()[device_type].abilities:
        assert set(a.predicates) <= standard, a.name
        for predicate in a.predicates.values():
            assert parse_predicate(str(predicate)) == predicate


def test_only_the_robot_is_unsafe_for_random_commands() -> None:
    unsafe = {name for name, r in every_resource().items() if r.unsafe_for_random_commands}
    assert unsafe == {"ur"}


def test_instance_names_prefix_every_path() -> None:
    resource = nutrunner("nr2")
    assert {v.path for v in resource.variables} == {"nr2.run_c", "nr2.run_m", "nr2.tqr_m", "nr2.fail_m"}
    assert all(t.name.startswith("nr2.") for a in resource.abilities for t in a.transitions)


# --- nutrunner: the paper's table ------------------------------------------------------------
def test_nutrunner_is_the_paper_table() -> None:
    tighten = nutrunner().abilities[0]
    assert tighten.name == "nr.tighten"
    assert {name: str(p) for name, p in tighten.predicates.items()} == {
        "enabled": "!nr.run_c && !nr.run_m",
        "starting": "nr.run_c && !nr.run_m",
        "executing": "nr.run_c && nr.run_m && !nr.tqr_m && !nr.fail_m",
        "finished": "nr.run_c && nr.run_m && (nr.tqr_m || nr.fail_m)",
        "resetting": "!nr.run_c && nr.run_m",
    }
    kinds = {t.name: (t.kind, [[str(a) for a in o] for o in t.outcomes]) for t in tighten.transitions}
    assert kinds == {
        "nr.tighten.enabled": (TransitionKind.DELIBERATE, [["nr.run_c := true"]]),
        "nr.tighten.starting.effect": (TransitionKind.EFFECT, [["nr.run_m := true"]]),
        "nr.tighten.executing.effect": (TransitionKind.EFFECT, [["nr.tqr_m := true"], ["nr.fail_m := true"]]),
        "nr.tighten.finished": (TransitionKind.AUTOMATIC, [["nr.run_c := false"]]),
        "nr.tighten.resetting.effect": (TransitionKind.EFFECT,
                                        [["nr.run_m := false", "nr.tqr_m := false", "nr.fail_m := false"]]),
    }


@pytest.mark.parametrize(("outcome", "reported"), [(0, "nr.tqr_m"), (1, "nr.fail_m")])
def test_nutrunner_cycle_returns_to_enabled(outcome: int, reported: str) -> None:
    model = Model("nr", (nutrunner(),))
    state = model.initial_state()
    state = fire(model, state, "nr.tighten.enabled")
    state = fire(model, state, "nr.tighten.starting.effect")
    state = fire(model, state, "nr.tighten.executing.effect", outcome)
    assert state[reported] and not state["nr.run_c"]  # the automatic run_c := false fired at once
    state = fire(model, state, "nr.tighten.resetting.effect")
    assert state == model.initial_state()


# --- UR ------------------------------------------------------------------------------------
def test_ur_moves_only_along_allowed_moves() -> None:
    poses = ("home", "a", "b", "c")
    model = Model("ur", (ur(poses=poses, allowed_moves=[("home", "a"), ("a", "b")]),))
    for source in poses:
        at_rest = model.initial_state() | {"ur.pos_m": source, "ur.ref_pos_c": source}
        reachable = {name.split(".")[1].removeprefix("move_to_")
                     for name in enabled(model, at_rest, TransitionKind.DELIBERATE)}
        assert reachable == {"home": {"a"}, "a": {"home", "b"}, "b": {"a"}, "c": set()}[source]
    assert "ur.move_to_c" not in {a.name for a in model.abilities}  # nothing leads to c


def test_ur_move_leaves_then_arrives() -> None:
    model = Model("ur", (ur(poses=("home", "a"), allowed_moves=[("home", "a")]),))
    state = fire(model, model.initial_state(), "ur.move_to_a.enabled")
    assert state["ur.ref_pos_c"] == "a" and state["ur.pos_m"] == "home"
    assert enabled(model, state, TransitionKind.DELIBERATE) == set()  # no new target while not at rest
    state = fire(model, state, "ur.move_to_a.starting.effect")
    assert state["ur.pos_m"] == "unknown"
    state = fire(model, state, "ur.move_to_a.executing.effect")
    assert state["ur.pos_m"] == "a"
    assert model.abilities[1].predicates["finished"].eval(state)


def test_ur_in_protective_stop_neither_accepts_nor_makes_a_move() -> None:
    model = Model("ur", (ur(poses=("home", "a"), allowed_moves=[("home", "a")]),))
    stopped = model.initial_state() | {"ur.prot_stop_m": True}
    assert enabled(model, stopped, TransitionKind.DELIBERATE) == set()
    sent = stopped | {"ur.ref_pos_c": "a"}
    assert enabled(model, sent, TransitionKind.EFFECT) == set()


@pytest.mark.parametrize(("poses", "moves", "home", "message"), [
    (("home", "a"), [("home", "b")], "home", "'b', which is not a pose"),
    (("a", "b"), [("a", "b")], "home", "home pose 'home'"),
    (("home", "unknown"), [], "home", "between poses"),
])
def test_ur_refuses_a_bad_pose_graph(poses: tuple[str, ...], moves: list[tuple[str, str]], home: str,
                                     message: str) -> None:
    with pytest.raises(ValueError, match=message):
        ur(poses=poses, allowed_moves=moves, home=home)


# --- tool changer and dock ---------------------------------------------------------------
def goto(model: Model, state: State, pose: str) -> State:
    state = fire(model, state, f"ur.move_to_{pose}.enabled")
    state = fire(model, state, f"ur.move_to_{pose}.starting.effect")
    return fire(model, state, f"ur.move_to_{pose}.executing.effect")


def test_tool_is_picked_up_leaves_home_and_returns() -> None:
    model = robot_cell()
    state = goto(model, model.initial_state(), "dock_nutrunner")
    state = fire(model, state, "rsp.lock.enabled")
    assert enabled(model, state, TransitionKind.EFFECT) == {"rsp.lock.pick_up_nutrunner"}
    state = fire(model, state, "rsp.lock.pick_up_nutrunner")
    assert state["rsp.locked_m"] and state["rsp.tool_m"] == "nutrunner"
    assert state["dock.nutrunner_home_m"]  # still in its slot until the robot moves off
    state = fire(model, state, "ur.move_to_home.enabled")
    state = fire(model, state, "ur.move_to_home.starting.effect")
    state = fire(model, state, "dock.nutrunner_leaves.executing.effect")
    assert not state["dock.nutrunner_home_m"]
    state = fire(model, state, "ur.move_to_home.executing.effect")
    state = goto(model, state, "dock_nutrunner")
    state = fire(model, state, "rsp.unlock.enabled")
    assert enabled(model, state, TransitionKind.EFFECT) == {"rsp.unlock.put_down_nutrunner"}
    state = fire(model, state, "rsp.unlock.put_down_nutrunner")
    state = fire(model, state, "dock.nutrunner_returns.executing.effect")
    assert state == model.initial_state() | {"ur.pos_m": "dock_nutrunner", "ur.ref_pos_c": "dock_nutrunner"}


def test_locking_away_from_the_dock_couples_no_tool() -> None:
    model = robot_cell()
    # The controller locks only where it picks a tool up: never sent on the way, the lock closes at once.
    assert "rsp.lock.enabled" not in enabled(model, model.initial_state(), TransitionKind.DELIBERATE)
    state = model.initial_state() | {"rsp.lock_c": True}  # a lock commanded before, the robot at home
    assert enabled(model, state, TransitionKind.EFFECT) == {"rsp.lock.starting.effect"}
    state = fire(model, state, "rsp.lock.starting.effect")
    assert state["rsp.locked_m"] and state["rsp.tool_m"] == "none"


def test_no_lock_or_unlock_without_pressure() -> None:
    model = robot_cell()
    state = model.initial_state() | {"rsp.pressure_ok_m": False}
    assert enabled(model, state, TransitionKind.DELIBERATE) == enabled(
        model, model.initial_state(), TransitionKind.DELIBERATE) - {"rsp.lock.enabled"}
    assert enabled(model, state | {"rsp.lock_c": True}, TransitionKind.EFFECT) == set()


def test_a_handheld_tool_leaves_while_the_operator_uses_it() -> None:
    model = Model("cell", (ur(poses=ROBOT_POSES, allowed_moves=ROBOT_MOVES), rsp(),
                           dock(handheld_tasks={"nutrunner": ["tighten_by_hand"]}),
                           operator(tasks=("tighten_by_hand",))))
    state = fire(model, model.initial_state(), "human.tighten_by_hand.enabled")
    state = fire(model, state, "dock.nutrunner_leaves.executing.effect")
    assert not state["dock.nutrunner_home_m"]
    state = goto(model, state, "dock_nutrunner")
    assert "rsp.lock.enabled" not in enabled(model, state, TransitionKind.DELIBERATE)  # nothing to pick up
    assert "rsp.lock.pick_up_nutrunner" not in enabled(model, state | {"rsp.lock_c": True}, TransitionKind.EFFECT)
    state = fire(model, model.initial_state(), "human.tighten_by_hand.enabled")
    state = fire(model, state, "dock.nutrunner_leaves.executing.effect")
    state = fire(model, state, "human.tighten_by_hand.executing.effect")  # confirms: the instruction ends
    assert enabled(model, state, TransitionKind.EFFECT) == {"dock.nutrunner_returns.executing.effect",
                                                            "human.release_button.resetting.effect"}


def test_dock_refuses_poses_for_unknown_tools() -> None:
    with pytest.raises(ValueError, match="dock_poses"):
        dock(dock_poses={"screwdriver": "dock_screwdriver"})
    with pytest.raises(ValueError, match="handheld_tasks"):
        dock(handheld_tasks={"screwdriver": ["t"]})


# --- lift, MiR, AGV ----------------------------------------------------------------------
@pytest.mark.parametrize(("factory", "ability_name", "moving", "arrived"), [
    (lift, "lift.move_up", "between", "up"),
    (mir, "mir.goto_station", "moving", "at_station"),
    (agv, "agv.goto_station", "moving", "at_station"),
])
def test_goto_leaves_then_arrives(factory: type, ability_name: str, moving: str, arrived: str) -> None:
    resource = factory()
    model = Model("one", (resource,))
    position = f"{resource.name}.pos_m"
    state = fire(model, model.initial_state(), f"{ability_name}.enabled")
    state = fire(model, state, f"{ability_name}.starting.effect")
    assert state[position] == moving
    state = fire(model, state, f"{ability_name}.executing.effect")
    assert state[position] == arrived
    assert enabled(model, state, TransitionKind.EFFECT) == set()


def test_agv_leaves_through_the_exit_and_lift_reverses_midway() -> None:
    model = Model("one", (agv(),))
    state = model.initial_state() | {"agv.goto_c": "station", "agv.pos_m": "at_station"}
    for step in ("enabled", "starting.effect", "executing.effect"):
        state = fire(model, state, f"agv.goto_exit.{step}")
    assert state["agv.pos_m"] == "away" and state["agv.engine_m"]
    model = Model("one", (lift(),))
    state = fire(model, model.initial_state(), "lift.move_up.enabled")
    state = fire(model, state, "lift.move_up.starting.effect")
    state = fire(model, state, "lift.move_down.enabled")
    state = fire(model, state, "lift.move_down.executing.effect")
    assert state == model.initial_state()


# --- RFID, camera, operator ----------------------------------------------------------------
def test_rfid_verifies_once_a_badge_is_scanned() -> None:
    model = Model("rfid", (rfid(),))
    state = fire(model, model.initial_state(), "rfid.verify.executing.effect")
    assert state["rfid.verified_m"]
    assert enabled(model, state, TransitionKind.EFFECT) == set()


def test_camera_sees_the_operator_where_the_instruction_sends_them() -> None:
    model = Model("op", (operator(tasks=("fetch", "assemble", "call")),
                         camera(task_zones={"fetch": "robot", "assemble": "shared"})))
    state = fire(model, model.initial_state(), "human.fetch.enabled")
    assert enabled(model, state, TransitionKind.EFFECT) >= {"cam.sees_robot.executing.effect"}
    state = fire(model, state, "cam.sees_robot.executing.effect")
    assert state["cam.zone_m"] == "robot"
    state = fire(model, state, "human.fetch.executing.effect")
    assert state["human.instr_c"] == "none"
    state = fire(model, state, "cam.sees_outside.executing.effect")
    state = fire(model, state, "human.release_button.resetting.effect")
    state = fire(model, state, "human.call.enabled")  # a task with no zone keeps the operator outside
    assert not any(name.startswith("cam.") for name in enabled(model, state, TransitionKind.EFFECT))


def test_camera_refuses_unknown_zones() -> None:
    with pytest.raises(ValueError, match="task_zones"):
        camera(task_zones={"fetch": "kitchen"})


def test_operator_protocol() -> None:
    model = Model("op", (operator(tasks=("fetch", "assemble")),))
    state = model.initial_state()
    assert enabled(model, state, TransitionKind.DELIBERATE) == {"human.fetch.enabled", "human.assemble.enabled"}
    state = fire(model, state, "human.fetch.enabled")
    assert enabled(model, state, TransitionKind.DELIBERATE) == set()  # one task at a time
    state = fire(model, state, "human.fetch.executing.effect")
    assert state == {"human.instr_c": "none", "human.done_m": True}  # withdrawn at once
    assert enabled(model, state, TransitionKind.DELIBERATE) == set()  # until the button is released
    state = fire(model, state, "human.release_button.resetting.effect")
    assert state == model.initial_state()


def test_operator_confirms_only_when_possible_and_records_it() -> None:
    seated = estimated("engine.frame_e", Domain.enum("loose", "seated"), "loose")
    ready = estimated("engine.ready_e", initial=False)
    human = operator(tasks=("seat",), confirm_when={"seat": "engine.ready_e"},
                     on_confirm={"seat": ["engine.frame_e := seated"]})
    model = Model("op", (human,), estimated=(seated, ready))
    state = fire(model, model.initial_state(), "human.seat.enabled")
    assert enabled(model, state, TransitionKind.EFFECT) == set()
    state = fire(model, state | {"engine.ready_e": True}, "human.seat.executing.effect")
    assert state["engine.frame_e"] == "seated" and state["human.instr_c"] == "none"


def test_instruct_when_says_when_a_task_may_be_asked_for() -> None:
    part = estimated("engine.part_e", Domain.enum("absent", "mounted", "tightened"), "absent")
    human = operator(tasks=("mount", "wave"), on_confirm={"mount": ["engine.part_e := mounted"]},
                     instruct_when={"mount": "engine.part_e == absent"})
    model = Model("op", (human,), estimated=(part,))
    moved_on = model.initial_state() | {"engine.part_e": "tightened"}
    assert enabled(model, model.initial_state(), TransitionKind.DELIBERATE) == {"human.mount.enabled",
                                                                               "human.wave.enabled"}
    assert enabled(model, moved_on, TransitionKind.DELIBERATE) == {"human.wave.enabled"}  # no guard: always


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"tasks": ("none",)}, "no instruction"),
    ({"tasks": ("a",), "instruct_when": {"b": True}}, "instruct_when"),
    ({"tasks": ("a",), "confirm_when": {"b": True}}, "confirm_when"),
    ({"tasks": ("a",), "on_confirm": {"b": []}}, "on_confirm"),
])
def test_operator_refuses_bad_tasks(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        operator(**kwargs)


def test_a_cross_resource_reference_is_checked_by_the_model() -> None:
    with pytest.raises(ModelError, match=r"unknown variable ur\.pos_m"):
        Model("alone", (rsp(),))


# --- the paper's door example ------------------------------------------------------------
@pytest.fixture
def door() -> Resource:
    """A door with no position sensor: the controller estimates where it is (`pos_e`)
    from what it commanded (`refpos_c`); a lock it does not control is measured (`locked_m`)."""
    positions = Domain.enum("closed", "opened")
    refpos_c = command("door.refpos_c", positions, "closed")
    pos_e = estimated("door.pos_e", positions, "closed")
    locked_m = measured("door.locked_m")

    def move(verb: str, target: str, source: str) -> Ability:
        return ability(
            f"door.{verb}",
            enabled=Phase(f"door.refpos_c == {source} && door.pos_e == {source} && !door.locked_m",
                          deliberate=f"door.refpos_c := {target}"),
            executing=Phase(f"door.refpos_c == {target} && door.pos_e == {source}",
                            automatic=f"door.pos_e := {target}", guard="!door.locked_m"),
            finished=f"door.refpos_c == {target} && door.pos_e == {target}",
        )

    key = ability("door.key",
                  executing=Phase("door.pos_e == closed", effects=["door.locked_m := true", "door.locked_m := false"]))
    moves = (move("open", "opened", "closed"), move("close", "closed", "opened"))
    return Resource("door", (refpos_c, pos_e, locked_m), (*moves, key))


def test_door_model(door: Resource) -> None:
    model = Model("door", (door,))
    state = model.initial_state()
    assert [v.path for v in door.estimated] == ["door.pos_e"]
    assert enabled(model, state, TransitionKind.DELIBERATE) == {"door.open.enabled"}
    state = fire(model, state, "door.open.enabled")
    assert state["door.pos_e"] == "opened"  # estimated at once: nothing measures it
    assert model.abilities[0].predicates["finished"].eval(state)
    state = fire(model, state, "door.close.enabled")
    locked = fire(model, state, "door.key.executing.effect", outcome=0)
    assert enabled(model, locked, TransitionKind.DELIBERATE) == set()


def test_door_effect_may_not_write_the_estimate(door: Resource) -> None:
    wrong = ability("door.wind", executing=Phase("door.pos_e == opened", effects=["door.pos_e := closed"]))
    with pytest.raises(ModelError, match="effects write measured variables only"):
        Model("door", (door.with_abilities([wrong]),))
