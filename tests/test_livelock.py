"""The controller notices when it goes round in circles (controller/livelock.py): the same goals asked again
from a state already seen since the last progress are planned afresh, then put in error."""

from __future__ import annotations

import dataclasses
import math

import pytest

from common.model import OperationState, Resource, Transition, measured
from common.model.compiled import CompiledModel
from common.wire.ctl import Livelock, ReplanCause, ReplanReason
from controller.control import ControlCore
from controller.livelock import GIVE_UP_AFTER, LOOP_AFTER, LivelockWatch, Repeat
from controller.planner import Plan, Planner
from tests.test_control import lamp_beside_a_gauge

GOALS = frozenset({"LampOn"})


def test_the_watch_counts_requests_from_a_state_until_an_operation_finishes() -> None:
    watch = LivelockWatch()
    here = ("a",)
    assert watch.asked(GOALS, here) == (Repeat.FIRST, 1)
    assert watch.asked(GOALS, here) == (Repeat.AGAIN, 2)
    assert watch.asked(frozenset({"Other"}), here) == (Repeat.FIRST, 1)
    assert watch.asked(GOALS, here) == (Repeat.LOOP, LOOP_AFTER)
    watch.finished()
    assert watch.asked(GOALS, here) == (Repeat.FIRST, 1)
    for count in range(2, GIVE_UP_AFTER):
        assert watch.asked(GOALS, here)[1] == count
    assert watch.asked(GOALS, here) == (Repeat.GIVE_UP, GIVE_UP_AFTER)


def lamp_core() -> ControlCore:
    compiled = CompiledModel(lamp_beside_a_gauge())
    core = ControlCore(compiled, Planner(compiled), clock=lambda: 0.0)
    core.request("LampOn")
    core.tick()
    return core


def test_asked_again_from_the_same_state_the_planner_searches_instead_of_handing_back_its_plan() -> None:
    core = lamp_core()
    first = core.plan_request()
    assert first is not None and first.reuse
    answer = core.solve(first)
    assert isinstance(answer, Plan) and answer.stats.method != "reused"
    core.adopt(first, answer)
    core.load({})  # a restart: plan again, from the same state
    again = core.plan_request()
    assert again is not None and again.start == first.start and not again.reuse
    answer = core.solve(again)
    assert isinstance(answer, Plan) and answer.stats.method != "reused"


def plan_and_restart(core: ControlCore, times: int) -> None:
    """`times` rounds: a plan for LampOn asked and taken, then a restart from the same state."""
    for _ in range(times):
        request = core.plan_request()
        assert request is not None and set(request.goals) == {"LampOn"}
        core.adopt(request, core.solve(request))
        core.load({})


def test_the_same_goals_asked_twenty_times_from_one_state_go_to_error_and_wait_for_the_operator() -> None:
    core = lamp_core()
    plan_and_restart(core, GIVE_UP_AFTER - 1)
    request = core.plan_request()
    assert request is not None and not request.goals
    assert core.op_state("LampOn") is OperationState.ERROR
    assert math.isinf(core.errors["LampOn"].retry_at) and core.next_retry() is None
    assert core.error_text("LampOn").startswith(f"livelock: no progress in {GIVE_UP_AFTER} plans from one state")
    said = [event for event in core.events.log if isinstance(event, Livelock)]
    assert said == [Livelock(["LampOn"], "", f"no progress in {GIVE_UP_AFTER} plans from one state", GIVE_UP_AFTER)]
    core.adopt(request, core.solve(request))
    core.withdraw("LampOn", ReplanCause(ReplanReason.RESET_BY_OPERATOR, "LampOn"))  # and starts it again:
    core.request("LampOn")
    core.tick()
    request = core.plan_request()  # counted afresh
    assert request is not None and set(request.goals) == {"LampOn"} and request.reuse


def test_replans_because_health_changes_are_no_circle_however_many_from_one_state() -> None:
    # A hub's link that flaps while the operator works on one task: the station asks again from one state
    # at each change, and does nothing wrong. (Before: 20 such requests put the operations in error.)
    lamp = lamp_beside_a_gauge()
    fan = Resource("f", (measured("f.spin_m"),), ())  # a device no plan needs, whose hub flaps
    compiled = CompiledModel(dataclasses.replace(lamp, resources=(*lamp.resources, fan)))
    core = ControlCore(compiled, Planner(compiled), clock=lambda: 0.0)
    core.request("LampOn")
    core.tick()
    for flap in range(2 * GIVE_UP_AFTER):
        request = core.plan_request()
        assert request is not None and set(request.goals) == {"LampOn"}, flap
        core.adopt(request, core.solve(request))
        core.set_disabled(frozenset({"f"}) if flap % 2 == 0 else frozenset())
    assert core.op_state("LampOn") is not OperationState.ERROR
    assert not [event for event in core.events.log if isinstance(event, Livelock)]
    request = core.plan_request()
    assert request is not None
    core.adopt(request, core.solve(request))
    core.load({})  # rounds that count still do: the 20th from this state (the first request was one) gives up
    plan_and_restart(core, GIVE_UP_AFTER - 2)
    request = core.plan_request()
    assert request is not None and not request.goals
    assert core.op_state("LampOn") is OperationState.ERROR


def test_a_tightening_that_fails_again_and_again_from_one_state_is_no_livelock(monkeypatch: pytest.MonkeyPatch) -> None:
    """The nutrunner's effect has two outcomes (torque reached, failed): failing five times in a row at one bolt
    brings the station back to one state five times, but the effect happened each time, with the other outcome:
    nothing took its condition away, so it is retried, not put in error as a livelock. (Before, the third failure
    was diagnosed "nr.tqr_m never became true" and a 200-order run with --fail-rate 0.2 ran out of retries.)"""
    from deploy.local.inprocess import run_in_process
    from hubs.emulator import EffectEmulator
    from tests.fault_station.model import bolt_station

    failures = {"left": 5}
    chosen = EffectEmulator._choose

    def fail_first(self: EffectEmulator, t: Transition) -> int:
        outcome = chosen(self, t)
        if len(t.outcomes) > 1 and failures["left"] > 0:
            failures["left"] -= 1
            return 1
        return outcome

    monkeypatch.setattr(EffectEmulator, "_choose", fail_first)
    summary = run_in_process(bolt_station("failing", (1,)), seed=1)
    assert failures["left"] == 0  # the five failures happened
    assert summary.finished, summary.reason
    assert not [line for line in summary.log if "livelock" in line or "error" in line], summary.log


def test_a_move_whose_start_and_arrival_come_in_one_measurement_is_not_lost() -> None:
    """Under load a robot's move can start and arrive between two measurements: its start effect (pos_m :=
    unknown) is never seen, yet nothing took its condition away. Before, that was "ur.pos_m never became
    unknown … left above_engine (now at_frame)", and three of them a livelock of a healthy station (a fresh
    clone's suite, the reference station at speed 20 beside two other test workers)."""
    from controller.engine import PlanProgress
    from tests.fault_station.model import bolt_station
    from tests.test_engine import plan_for

    compiled = CompiledModel(bolt_station("moves", (1,)))
    start = compiled.initial()
    plan = plan_for(compiled, start, "ur.pos_m == at_bolt1")
    progress = PlanProgress(compiled, plan)
    commanded = plan.states[1]  # the move commanded: its start effect is due
    progress.done.add(0)
    progress.note_due(commanded)
    arrived = compiled.with_values(commanded, {"ur.pos_m": "at_bolt1"})
    assert progress.lost_effect(compiled, arrived) is None
    # Taken away by something else (the command withdrawn before the robot moved): lost, and said so.
    withdrawn = compiled.with_values(commanded, {"ur.ref_pos_c": "home"})
    lost = progress.lost_effect(compiled, withdrawn)
    assert lost is not None and "ur.pos_m never became unknown" in lost.never, lost
