"""Supervisor synthesis: forbidden states become guards on deliberate transitions; uncontrollable
chains into a forbidden state are cut at the last deliberate step; an uncontrollable model is refused."""

from __future__ import annotations

import itertools

import pytest

from common.model import Domain, Model, Phase, Resource, ability, command, estimated, forbid, measured
from common.model.compiled import CompiledModel
from controller.synthesis import SynthesisError, synthesize


def robot_and_operator(extra_specs: tuple = ()) -> Model:
    """A robot that moves (deliberate ref, then an effect) and an operator told to enter a zone."""
    ref = command("r.ref_c", Domain.enum("home", "shared"), "home")
    pos = measured("r.pos_m", Domain.enum("home", "moving", "shared"))
    moves = [
        ability(f"r.to_{p}",
                enabled=Phase((ref == pos) & (ref != p), deliberate=f"r.ref_c := {p}"),
                starting=Phase((ref == p) & (pos != p) & (pos != "moving"), effects="r.pos_m := moving"),
                executing=Phase((ref == p) & (pos == "moving"), effects=f"r.pos_m := {p}"))
        for p in ("home", "shared")
    ]
    zone = command("h.zone_c", Domain.enum("outside", "robot"), "outside")
    walk = [ability(f"h.go_{z}", enabled=Phase(zone != z, deliberate=f"h.zone_c := {z}")) for z in ("outside", "robot")]
    return Model(
        "zones",
        (Resource("r", (ref, pos), tuple(moves)), Resource("h", (zone,), tuple(walk))),
        specifications=(forbid("robot_in_shared_with_operator", "r.pos_m == shared && h.zone_c == robot"),
                        *extra_specs),
    )


def reachable(model: Model, guards: dict) -> set[tuple]:
    c = CompiledModel(model, guards)
    seen = {c.close(c.initial())[0]}
    todo = list(seen)
    while todo:
        s = todo.pop()
        for t in itertools.chain(c.deliberate, c.effects):
            if t.guard(s):
                for outcome in t.outcomes:
                    n, _ = c.close(outcome(s))
                    if n not in seen:
                        seen.add(n)
                        todo.append(n)
    return {tuple(c.unpack(s).items()) for s in seen}


def test_guards_keep_every_reachable_state_out_of_the_forbidden_ones() -> None:
    model = robot_and_operator()
    supervisor = synthesize(model)
    # The robot may not be sent towards the shared pose while the operator is in the robot zone ...
    assert "h.zone_c" in str(supervisor.guards["r.to_shared.enabled"])
    # ... and the operator may not be sent in while the robot is there or on its way (an uncontrollable effect).
    guard = str(supervisor.guards["h.go_robot.enabled"])
    assert "r.pos_m" in guard and "r.ref_c" in guard
    states = reachable(model, supervisor.guards)
    forbidden = model.specifications[0].forbidden
    assert not any(forbidden.eval(dict(s)) for s in states)
    # Without the supervisor the forbidden state is reachable: the test can fail.
    assert any(forbidden.eval(dict(s)) for s in reachable(model, {}))


def test_the_guards_are_not_stricter_than_needed() -> None:
    model = robot_and_operator()
    supervisor = synthesize(model)
    states = reachable(model, supervisor.guards)
    # The operator can still enter the robot zone while the robot is home and idle.
    assert any(dict(s)["h.zone_c"] == "robot" and dict(s)["r.pos_m"] == "home" for s in states)
    assert any(dict(s)["r.pos_m"] == "shared" for s in states)


def test_an_uncontrollable_model_is_refused_with_a_trace() -> None:
    flag = estimated("x.started_e", initial=True)
    sensor = measured("x.alarm_m")
    fire = ability("x.alarm", executing=Phase("x.started_e && !x.alarm_m", effects="x.alarm_m := true"))
    model = Model("doomed", (Resource("x", (flag, sensor), (fire,)),),
                  specifications=(forbid("no_alarm", "x.alarm_m"),))
    with pytest.raises(SynthesisError) as info:
        synthesize(model)
    assert info.value.trace == ["x.alarm.executing.effect [effect]: x.alarm_m := true"]
    assert "no_alarm" in str(info.value)


def test_the_reference_station_is_controllable_and_guards_robot_moves() -> None:
    from common.stations.engine_assembly import build_model

    supervisor = synthesize(build_model())
    assert all(supervisor.converged.values())
    guard = str(supervisor.guards["ur.move_to_at_bolt7.enabled"])
    assert "human.instr_c" in guard and "cam.zone_m" in guard
