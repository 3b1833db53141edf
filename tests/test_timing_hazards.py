"""Timing hazards named before a run (controller/timing_hazards.py, `hubctl check`): one small model per
kind, written with `common.model` in tests/stations/timing.py, and a safe one with none."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.model import TRUE, Duration, Model, parse_predicate
from common.model.satisfiable import satisfiable
from common.resources import durations_of
from controller.timing_hazards import HazardKind, TimingHazard, timing_hazards
from deploy.cli import main
from tests.stations.timing import (
    command_disables_station,
    feeder_station,
    safe_station,
    sensed_device_station,
    transient_station,
)


def hazards_of(model: Model, **configured: Duration) -> list[TimingHazard]:
    return timing_hazards(model, durations_of(model, configured))


def test_an_effect_reading_a_device_that_commands_move() -> None:
    [hazard] = hazards_of(sensed_device_station())
    assert hazard.kind is HazardKind.SENSED_DEVICE_MOVES
    assert (hazard.subject, hazard.variable, hazard.transitions) == (
        "f.sees.executing.effect", "r.pos_m", ("r.move_to_home.enabled",))
    # the sensor takes the fallback 0.2 s, the robot leaves 0.15 s after the command
    assert "the command wins the race: f's effect takes up to 0.2 s, r.pos_m changes 0.15 s after the command " \
           "(r.move_to_home.starting.effect)" in hazard.text
    assert "guard those commands with f.sees.executing.effect's result (f.seen_m := true)" in hazard.remedy
    assert "keep f's duration (now 0.2 s) below the 0.15 s r takes to change r.pos_m" in hazard.remedy


def test_durations_that_keep_the_sensor_ahead_are_said_to_be_safe_by_timing_only() -> None:
    [hazard] = hazards_of(sensed_device_station(), f=Duration(0.05, 0.1))
    assert "the durations keep it safe, by timing only: f's effect takes at most 0.1 s" in hazard.text


def test_the_feeder_of_issue_21_is_named_with_both_of_its_readings() -> None:
    hazards = hazards_of(feeder_station())
    assert {(h.kind, h.subject, h.variable) for h in hazards} == {
        (HazardKind.SENSED_DEVICE_MOVES, "f.taken.executing.effect", "r.pos_m"),
        (HazardKind.SENSED_DEVICE_MOVES, "f.taken.executing.effect", "g.vac_m"),
    }
    moves = next(h for h in hazards if h.variable == "r.pos_m")
    assert moves.transitions == ("r.move_to_at_pallet.enabled", "r.move_to_home.enabled")


def test_a_command_that_disables_an_effect_that_is_due() -> None:
    [hazard] = hazards_of(command_disables_station())
    assert hazard.kind is HazardKind.COMMAND_DISABLES_EFFECT
    assert (hazard.subject, hazard.transitions) == ("c.run.executing.effect", ("c.stop.enabled",))
    assert hazard.text == ("c.run.executing.effect (c.at_m := true, 0.5-1 s) is disabled by c.stop.enabled "
                           "if given while it is due")
    assert "guard those commands with c.run.executing.effect's result (c.at_m := true)" in hazard.remedy


def test_tracking_that_needs_a_transient_value() -> None:
    [hazard] = hazards_of(transient_station())
    assert hazard.kind is HazardKind.TRACKING_NEEDS_TRANSIENT
    assert (hazard.subject, hazard.variable) == ("cell.count", "s.pulse_m")
    assert hazard.transitions == ("s.pulse.starting.effect", "s.fade.executing.effect")
    assert "the controller must see it within 0.05 s" in hazard.text
    assert "have the device hold s.pulse_m until a command resets it" in hazard.remedy


def test_a_safe_model_gets_no_warning() -> None:
    assert hazards_of(safe_station()) == []


def test_the_supervisors_guard_on_a_command_is_taken_into_account() -> None:
    model = sensed_device_station()
    # a synthesized guard that holds the robot until the sensor has seen it takes the race away
    held = timing_hazards(model, durations_of(model), {"r.move_to_home.enabled": parse_predicate("f.seen_m")})
    assert held == []
    assert timing_hazards(model, durations_of(model), {"r.move_to_home.enabled": TRUE}) != []


def test_satisfiable_finds_a_witness_or_shows_there_is_none() -> None:
    model = feeder_station()
    domains = {path: v.domain for path, v in model.variables.items()}
    found = satisfiable(parse_predicate("r.pos_m == at_feeder && g.vac_m && !f.present_m"), domains)
    assert found.witness == {"r.pos_m": "at_feeder", "g.vac_m": True, "f.present_m": False}
    none = satisfiable(parse_predicate("r.pos_m == at_feeder && (r.pos_m == home || g.vac_m && !g.vac_m)"), domains)
    assert none.witness is None and none.decided and not none.possible
    undecided = satisfiable(parse_predicate("r.pos_m == at_pallet && r.ref_pos_c == home && g.vac_m"), domains,
                            budget=1)
    assert undecided.possible and not undecided.decided


def test_hubctl_check_prints_durations_and_warns_of_hazards_without_failing(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", "--model", "tests.stations.timing:feeder_station"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    start = lines.index("durations of the effects, per resource (type, seconds, declared by):")
    assert [line.split()[:3] for line in lines[start + 1:start + 4]] == [
        ["r", "ur", "0.15"], ["g", "vacuum_gripper", "0.1"], ["f", "box_feeder", "0.2"]]
    assert "  warning: f's type 'box_feeder' declares no duration: its effects run on the fallback guess 0.2 s" \
           in lines
    assert "timing hazards: 2 (warnings: a plan may count on an effect the station does not wait for)" in lines
    assert sum(line.startswith("  warning [an effect reads another device that commands change]: "
                               "f.taken.executing.effect") for line in lines) == 2
    assert lines[-1].startswith("checked 1 operations in ") and lines[-1].endswith(": 0 unreachable")


def test_hubctl_check_of_a_safe_model(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check", "--model", "tests.stations.timing:safe_station"]) == 0
    out = capsys.readouterr().out
    assert "timing hazards: 0 " in out
    assert "fallback" not in out


def test_hubctl_check_takes_the_durations_of_hubs_toml(capsys: pytest.CaptureFixture[str]) -> None:
    """The feeder station of the engine's race hold (tests/timing_stations), its delays in its hubs.toml."""
    config = Path(__file__).resolve().parent / "timing_stations" / "hubs.toml"
    assert main(["check", "--config", str(config)]) == 0
    lines = capsys.readouterr().out.splitlines()
    feeder = next(line for line in lines if line.split()[:2] == ["f", "box_feeder"])
    assert feeder.split()[2:] == ["0.2", "s", "hubs.toml", "delay"]
    assert any(line.startswith("  warning [an effect reads another device that commands change]: f.taken")
               and "the command wins the race: f's effect takes up to 0.2 s" in line for line in lines)
