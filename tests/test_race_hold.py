"""The engine holds a plan command while it would overtake an effect the plan needs that is due on the measured
state (DESIGN.md §4), bounded by the effect's duration; and it names an effect the plan lost."""

from __future__ import annotations

from common.model.compiled import CompiledModel, State
from common.wire.ctl import ReplanReason
from controller.engine import HOLD_BOUND_FACTOR, Engine, PlanProgress
from controller.planner import Plan, Planner
from controller.planner.steps import RaceCheck
from tests.timing_stations.feeder import FEEDER_DELAY, build_model

MOVE_AWAY = "r.move_to_at_pallet.enabled"
TAKEN = "f.taken.effect"


def feeder_plan() -> tuple[CompiledModel, Plan]:
    compiled = CompiledModel(build_model())
    start = compiled.with_values(compiled.initial(), {"cell.box_e": "on_feeder", "op.Place": "executing"})
    plan = Planner(compiled).plan(start, {"Place": compiled.model.operation_by_name["Place"].goal})
    assert isinstance(plan, Plan), plan
    names = [s.transition for s in plan.steps]
    # The plan sends the robot on before the vacuum holds, as predicted: the sensor's effect is not due yet there.
    assert names.index(MOVE_AWAY) < names.index("g.grip.executing.effect") < names.index(TAKEN)
    return compiled, plan


def at_the_feeder_gripping(compiled: CompiledModel, engine: Engine, progress: PlanProgress, now: float) -> State:
    """The robot arrived at the feeder after the vacuum took hold: the measured state is ahead of the plan."""
    state = engine.tick(progress.plan.states[0], progress=progress, now=now).state
    assert progress.done  # the move to the feeder and the grip were sent
    state = engine.tick(compiled.with_values(state, {"r.pos_m": "unknown"}), progress=progress, now=now).state
    return compiled.with_values(state, {"r.pos_m": "at_feeder", "g.vac_m": True})


def test_the_command_that_would_overtake_a_due_effect_is_held_until_the_effect_happened() -> None:
    compiled, plan = feeder_plan()
    engine = Engine(compiled)
    progress = PlanProgress(compiled, plan)
    state = at_the_feeder_gripping(compiled, engine, progress, now=0.0)
    tick = engine.tick(state, progress=progress, now=0.3)
    assert MOVE_AWAY not in tick.fired and tick.replan is None
    assert [(h.transition, h.waits_for) for h in tick.held] == [(MOVE_AWAY, TAKEN)]
    tick = engine.tick(tick.state, progress=progress, now=0.3 + FEEDER_DELAY)
    assert MOVE_AWAY not in tick.fired and tick.replan is None
    taken = compiled.with_values(tick.state, {"f.present_m": False})
    tick = engine.tick(taken, progress=progress, now=0.3 + FEEDER_DELAY)
    assert MOVE_AWAY in tick.fired and tick.held == [] and tick.replan is None
    assert tick.changed_commands == {"r.ref_c": "at_pallet"}


def test_a_hold_longer_than_the_effect_takes_asks_for_a_replan_naming_the_step_and_the_effect() -> None:
    compiled, plan = feeder_plan()
    engine = Engine(compiled)
    progress = PlanProgress(compiled, plan)
    state = at_the_feeder_gripping(compiled, engine, progress, now=0.0)
    engine.tick(state, progress=progress, now=1.0)
    bound = HOLD_BOUND_FACTOR * FEEDER_DELAY
    assert engine.tick(state, progress=progress, now=1.0 + bound).replan is None
    tick = engine.tick(state, progress=progress, now=1.0 + bound + 0.01)
    assert tick.replan is not None and tick.replan.reason is ReplanReason.RACE_HOLD_EXPIRED
    step = [s.transition for s in plan.steps].index(MOVE_AWAY)
    assert tick.replan.detail.startswith(f"step {step} {MOVE_AWAY} held 0.41 s for {TAKEN}")
    assert tick.lost is not None and tick.lost.effect == TAKEN
    assert MOVE_AWAY not in tick.fired


def test_without_a_clock_the_hold_has_no_bound() -> None:
    compiled, plan = feeder_plan()
    engine = Engine(compiled)
    progress = PlanProgress(compiled, plan)
    state = at_the_feeder_gripping(compiled, engine, progress, now=0.0)
    for _ in range(3):
        tick = engine.tick(state, progress=progress)
        assert tick.replan is None and [h.transition for h in tick.held] == [MOVE_AWAY]


def test_the_state_leaving_the_plan_names_the_effect_it_lost_and_what_took_its_condition_away() -> None:
    compiled, plan = feeder_plan()
    engine = Engine(compiled)
    progress = PlanProgress(compiled, plan)
    state = engine.tick(plan.states[0], progress=progress).state
    # The plan's own order: the robot arrives and is sent on; then the vacuum holds: the sensor's effect is due.
    state = engine.tick(compiled.with_values(state, {"r.pos_m": "unknown"}), progress=progress).state
    tick = engine.tick(compiled.with_values(state, {"r.pos_m": "at_feeder"}), progress=progress)
    assert MOVE_AWAY in tick.fired
    state = engine.tick(compiled.with_values(tick.state, {"g.vac_m": True}), progress=progress).state
    tick = engine.tick(compiled.with_values(state, {"r.pos_m": "unknown"}), progress=progress)
    assert tick.replan is not None and tick.replan.reason is ReplanReason.LEFT_PLAN and tick.lost is not None
    step = [s.transition for s in plan.steps].index(MOVE_AWAY)
    assert tick.lost.text == (f"f.present_m never became false ({TAKEN}): r.pos_m left at_feeder (now unknown) "
                              f"after step {step} {MOVE_AWAY}")


def test_the_planner_and_the_engine_share_one_race_test() -> None:
    compiled = CompiledModel(build_model())
    race = RaceCheck(compiled)
    move = compiled.by_name[MOVE_AWAY]
    racing = compiled.with_values(compiled.initial(), {"r.pos_m": "at_feeder", "r.ref_c": "at_feeder",
                                                       "g.vac_c": True, "g.vac_m": True})
    assert race.races(racing, move)
    assert [(r.started.name, r.due.name) for r in race.overtaking(racing, move)] == [
        ("r.move_to_at_pallet.starting.effect", TAKEN)]
    not_gripped = compiled.with_values(racing, {"g.vac_m": False})
    assert not race.races(not_gripped, move) and race.overtaking(not_gripped, move) == []
