"""The example stations beyond the reference one, and what running them needed.

* the machine-tending cell and the two-robot shared-workspace cell (common/stations/):
  valid, every operation reachable (`hubctl check`), their safety rules forbid what they
  say, and each runs to completion in process (virtual time) and as separate processes
  over Zenoh on loopback (the path `hubctl up --config examples/<station>/hubs.toml` takes);
* device types of a station's own (a conveyor, a CNC door): accepted in `emulate` mode by
  `hubctl config check` and the hubs, a clear error in `sim` or `real` mode;
* `hubctl up --in-process --config FILE` runs the model FILE names; `--model` wins;
* an operation whose precondition only a record makes true (nothing else is under way)
  starts in the same tick: such a run used to end "stuck: nothing can happen".
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from common.config.hubs_toml import ConfigError, load_config, load_station, parse_config
from common.config.modes import DeviceMode
from common.model import Model, OperationState, Value, estimated, operation, tracking
from common.model.compiled import CompiledModel
from common.resources import nutrunner, ur
from common.stations import load_model
from controller.engine import Engine
from deploy.cli import main as hubctl
from deploy.local.inprocess import run_in_process
from deploy.local.station import Options, run_station
from hubs.drivers.emulated import EmulatedDriver
from hubs.factory import build_drivers, check_devices, effective_mode

ROOT = Path(__file__).resolve().parent.parent
STATIONS = ("machine_tending", "shared_workspace")
CUSTOM_TYPES = {
    "machine_tending": {"gripper", "conveyor", "cnc", "cnc_door"},
    "shared_workspace": {"vacuum_gripper", "fixture"},
}


def example(station: str) -> Path:
    return ROOT / "examples" / station / "hubs.toml"


def example_text(station: str) -> str:
    """The example's hubs.toml, to be written elsewhere: its model file named by its absolute path."""
    model = ROOT / "examples" / station / "model.py"
    return example(station).read_text().replace('model = "model.py:build_model"', f'model = "{model}:build_model"')


def example_model(station: str) -> Model:
    """The example's model, from the file next to its hubs.toml."""
    return load_model(f"{ROOT / 'examples' / station / 'model.py'}:build_model")


@pytest.fixture(scope="module", params=sorted(STATIONS))
def station(request: pytest.FixtureRequest) -> tuple[str, Model]:
    name = request.param
    return name, example_model(name)


# --- the models ----------------------------------------------------------------------------------

def test_station_is_valid_and_of_a_realistic_size(station: tuple[str, Model]) -> None:
    name, model = station
    assert model.name == name and model.problems() == []
    assert 10 <= len(model.operations) <= 40
    assert {r.device_type for r in model.resources} >= CUSTOM_TYPES[name] | {"ur"}
    state = model.initial_state()
    assert [s.name for s in model.specifications if s.forbidden.eval(state)] == []


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(STATIONS))
def test_hubctl_check_finds_every_operation_reachable(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert hubctl(["check", "--model", f"{ROOT / 'examples' / name / 'model.py'}:build_model"]) == 0
    assert "0 unreachable" in capsys.readouterr().out


def _violated(model: Model, changes: dict[str, Value]) -> list[str]:
    state = model.initial_state() | changes
    return [s.name for s in model.specifications if s.forbidden.eval(state)]


ROBOT_IN_MACHINE = {"ur.ref_pos_c": "in_cnc", "ur.pos_m": "in_cnc"}
DOOR_OPEN = {"door.open_c": True, "door.pos_m": "open"}


@pytest.mark.parametrize(("changes", "violated"), [
    (ROBOT_IN_MACHINE, ["robot_in_machine_while_door_not_open"]),
    (ROBOT_IN_MACHINE | DOOR_OPEN, []),
    (ROBOT_IN_MACHINE | {"door.open_c": False, "door.pos_m": "open"}, ["robot_in_machine_while_door_not_open"]),
    (ROBOT_IN_MACHINE | {"door.open_c": True, "door.pos_m": "moving"}, ["robot_in_machine_while_door_not_open"]),
    # leaving the machine: between the chuck and the front, the door stays open
    ({"ur.ref_pos_c": "cnc_front", "ur.pos_m": "unknown", "door.pos_m": "moving"},
     ["robot_in_machine_while_door_not_open"]),
    ({"cnc.running_m": True, "cnc.clamp_c": True, "door.pos_m": "moving"}, ["spindle_runs_with_door_open"]),
    ({"cnc.running_m": True, "cnc.clamp_c": True}, []),
    ({"infeed.run_c": True, "ur.ref_pos_c": "at_infeed"}, ["infeed_runs_with_robot_at_pick"]),
    ({"outfeed.run_c": True, "ur.ref_pos_c": "above_outfeed", "ur.pos_m": "above_outfeed"}, []),
    ({"gripper.part_m": True, "ur.ref_pos_c": "above_infeed", "ur.pos_m": "above_infeed"}, ["part_dropped"]),
    ({"gripper.part_m": True, "cell.part1_e": "picked", "ur.ref_pos_c": "at_outfeed", "ur.pos_m": "unknown",
      "gripper.close_c": True}, ["raw_part_to_outfeed"]),
])
def test_machine_tending_specifications(changes: dict[str, Value], violated: list[str]) -> None:
    assert _violated(example_model("machine_tending"), changes) == violated


@pytest.mark.parametrize(("changes", "violated"), [
    ({"ur_a.ref_pos_c": "place1", "ur_a.pos_m": "place1", "ur_b.ref_pos_c": "screw2", "ur_b.pos_m": "unknown"},
     ["both_robots_in_shared_zone"]),
    # robot B on its way to its gate counts as in the zone (its origin is unknown between poses)
    ({"ur_a.ref_pos_c": "lift_product", "ur_a.pos_m": "gate", "ur_b.ref_pos_c": "gate", "ur_b.pos_m": "unknown"},
     ["both_robots_in_shared_zone"]),
    ({"ur_a.ref_pos_c": "place1", "ur_a.pos_m": "place1", "ur_b.ref_pos_c": "gate", "ur_b.pos_m": "gate"}, []),
    ({"ur_a.ref_pos_c": "tray2", "ur_a.pos_m": "tray2", "ur_b.ref_pos_c": "screw2", "ur_b.pos_m": "screw2"}, []),
    ({"vac_a.held_m": True, "cell.bracket1_e": "held", "ur_a.pos_m": "place2", "fixture.clamped_m": True},
     ["part_dropped"]),
    ({"vac_a.held_m": True, "cell.bracket1_e": "held", "ur_a.pos_m": "place1", "ur_a.ref_pos_c": "place1"},
     ["bracket_set_on_loose_product"]),
    ({"nr_b.run_m": True, "ur_b.pos_m": "screw1", "ur_b.ref_pos_c": "screw1"}, ["fastening_loose_product"]),
    ({"nr_b.run_m": True, "ur_b.pos_m": "bench1", "ur_b.ref_pos_c": "bench1"}, []),
])
def test_shared_workspace_specifications(changes: dict[str, Value], violated: list[str]) -> None:
    assert _violated(example_model("shared_workspace"), changes) == violated


# --- running them -------------------------------------------------------------------------------

def test_station_runs_to_completion_in_process(station: tuple[str, Model]) -> None:
    name, model = station
    summary = run_in_process(model, seed=0)
    figures = (f"{name} in process: {summary.operations_finished}/{summary.operations_total} operations, "
               f"{summary.abilities} abilities, {summary.plans} plans, {summary.replans} replans, "
               f"{summary.no_plans} goals without plan, station time {summary.emulated_seconds:.1f} s, "
               f"wall {summary.wall_seconds:.1f} s")
    print(figures)
    assert summary.finished, f"{figures}\n{summary.reason}\n" + "\n".join(summary.log[-10:])


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(STATIONS))
async def test_station_runs_to_completion_as_processes_over_zenoh(name: str, tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """`hubctl up --config examples/<station>/hubs.toml`: the controller and every hub as processes."""
    monkeypatch.chdir(ROOT)
    lines: list[str] = []
    began = time.monotonic()
    options = Options(config=str(example(name)), speed=2.0, run_dir=tmp_path, time_limit=180.0)
    code = await run_station(options, say=lines.append)
    output = "\n".join(lines)
    print(f"{name} over Zenoh: {time.monotonic() - began:.1f} s\n{lines[-1] if lines else ''}")
    total = len(example_model(name).operations)
    assert code == 0, output
    assert f"finished: {total}/{total} operations" in output, output


def test_in_process_up_runs_the_model_its_config_names(capsys: pytest.CaptureFixture[str]) -> None:
    config = str(ROOT / "tests" / "fault_station" / "hubs.toml")
    assert hubctl(["up", "--in-process", "--config", config]) == 0
    out = capsys.readouterr().out
    assert "running station fault_station" in out and "finished: 4/4 operations" in out


def test_in_process_up_prefers_an_explicit_model(capsys: pytest.CaptureFixture[str]) -> None:
    config = str(ROOT / "tests" / "fault_station" / "hubs.toml")
    assert hubctl(["up", "--in-process", "--config", config, "--model", "tests.test_stations:one_bolt"]) == 0
    out = capsys.readouterr().out
    assert "running station one_bolt" in out and "finished: 2/2 operations" in out


def test_up_over_processes_refuses_a_model_its_processes_would_not_load(capsys: pytest.CaptureFixture[str]) -> None:
    config = str(example("machine_tending"))
    assert hubctl(["up", "--config", config, "--model", "tests.test_stations:one_bolt"]) == 2
    err = capsys.readouterr().err
    assert "--model tests.test_stations:one_bolt" in err and "examples/machine_tending/model.py:build_model" in err


def test_up_names_a_missing_config(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    missing = str(tmp_path / "nope.toml")
    assert hubctl(["up", "--in-process", "--config", missing]) == 2
    assert f"{missing}: no such file (--config)" in capsys.readouterr().err


# --- an operation waiting only for a record --------------------------------------------------------

def one_bolt() -> Model:
    """The robot visits a checkpoint, recorded as it arrives; the bolt may be tightened only after that.

    Once the robot has arrived nothing is under way: no effect is pending, so no state change
    will come to start `TightenBolt`. It must start in the tick that records the visit."""
    return Model(
        "one_bolt",
        (ur("ur", ("home", "check", "bolt"), (("home", "check"), ("check", "bolt")), "home"), nutrunner("nr")),
        estimated=(estimated("cell.checked_e"), estimated("cell.bolt_e")),
        tracking=(
            tracking("cell.checked", "ur.pos_m == check && !cell.checked_e", "cell.checked_e := true"),
            tracking("cell.bolt_tightened", "nr.tqr_m && ur.pos_m == bolt && !cell.bolt_e", "cell.bolt_e := true"),
        ),
        operations=(
            operation("Check", "!cell.checked_e", "cell.checked_e"),
            operation("TightenBolt", "cell.checked_e && !cell.bolt_e", "cell.bolt_e"),
        ),
    )


def test_an_operation_whose_precondition_a_record_makes_true_starts_in_the_same_tick() -> None:
    compiled = CompiledModel(one_bolt())
    engine = Engine(compiled)
    started = engine.tick(compiled.initial(), requested=["Check", "TightenBolt"])
    assert started.started == ["Check"]
    arrived = compiled.with_values(started.state, {"ur.ref_pos_c": "check", "ur.pos_m": "check"})
    tick = engine.tick(arrived, requested=["Check", "TightenBolt"])
    # stage 2 records the visit, which finishes Check and lets TightenBolt start, all in this tick
    assert tick.finished == ["Check"] and tick.started == ["TightenBolt"]
    assert compiled.unpack(tick.state)["op.TightenBolt"] == OperationState.EXECUTING
    assert engine.tick(tick.state, requested=["Check", "TightenBolt"]).state == tick.state  # a fixpoint


def test_a_run_whose_last_event_is_a_record_does_not_stall() -> None:
    summary = run_in_process(one_bolt(), seed=0)
    assert summary.finished, summary.reason


# --- device types of a station's own ---------------------------------------------------------------

def test_station_types_are_accepted_in_emulate_mode(capsys: pytest.CaptureFixture[str]) -> None:
    for name in sorted(STATIONS):
        assert hubctl(["config", "check", "--config", str(example(name))]) == 0
        out = capsys.readouterr().out
        for device_type in CUSTOM_TYPES[name]:
            assert f"({device_type}, emulate)" in out


@pytest.mark.parametrize("mode", ["sim", "real"])
def test_a_station_type_outside_emulate_mode_names_type_hub_file_and_line(mode: str, tmp_path: Path) -> None:
    text = example_text("machine_tending")
    door = '[hubs.machine.devices.door]\ntype = "cnc_door"\nmode = "emulate"'
    assert door in text
    path = tmp_path / "hubs.toml"
    path.write_text(text.replace(door, door.replace('"emulate"', f'"{mode}"')))
    config = load_config(path)  # any type is a valid device; whether it has a driver is the hubs' question
    with pytest.raises(ConfigError) as caught:
        check_devices(config)
    line = text.splitlines().index('type = "cnc_door"') + 1
    assert len(caught.value.problems) == 1
    assert str(caught.value).startswith(
        f"{path}:{line}: hubs.machine.devices.door.type: no driver for device type 'cnc_door': none is built in ")
    assert "no installed package provides one under the entry-point group 'statehub.drivers'" in str(caught.value)
    assert f"(device in hub 'machine', mode '{mode}')" in str(caught.value)


def test_config_check_reports_a_station_type_in_sim_mode(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = example_text("shared_workspace").replace('type = "fixture"\nmode = "emulate"',
                                                            'type = "fixture"\nmode = "sim"')
    path = tmp_path / "hubs.toml"
    path.write_text(text)
    assert hubctl(["config", "check", "--config", str(path)]) == 1
    line = text.splitlines().index('type = "fixture"') + 1
    err = capsys.readouterr().err
    assert f"{path}:{line}: hubs.fixture.devices.fixture.type: no driver for device type 'fixture'" in err
    assert "entry-point group 'statehub.drivers'" in err


def test_a_misspelt_type_is_caught_against_the_model_with_the_other_problems(tmp_path: Path) -> None:
    text = example_text("machine_tending")
    text = text.replace('[hubs.conveyors.devices.outfeed]\ntype = "conveyor"',
                        '[hubs.conveyors.devices.outfeed]\ntype = "conveyer"')
    text = text.replace("lease_ms = 2000", "lease_ms = 20")
    path = tmp_path / "hubs.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as caught:
        load_station(path)
    assert [p.key for p in caught.value.problems] == ["network.lease_ms", "hubs.conveyors.devices.outfeed.type"]
    assert caught.value.problems[1].message == \
        "unknown device type 'conveyer', but resource 'outfeed' of the model is a 'conveyor'"
    assert caught.value.problems[1].line == text.splitlines().index('type = "conveyer"') + 1


def test_hubs_emulate_station_types_from_the_model_alone() -> None:
    config, model = load_station(example("machine_tending"))
    drivers = build_drivers(config, "conveyors", model)
    assert {type(d).__name__ for d in drivers.values()} == {"EmulatedDriver"}
    # the model says what its own device types do when commands stop, and how long an effect takes
    infeed = drivers["infeed"]
    assert isinstance(infeed, EmulatedDriver) and infeed.safe_values() == {"run_c": False}
    machine = build_drivers(config, "machine", model)
    door, cnc = machine["door"], machine["cnc"]
    assert isinstance(door, EmulatedDriver) and isinstance(cnc, EmulatedDriver)
    assert door.safe_values() == {}
    assert door.emulator.delay_of(model.transition_by_name["door.open.starting.effect"]) == 0.4
    assert cnc.emulator.delay_of(model.transition_by_name["cnc.cycle.starting.effect"]) == 0.5  # hubs.toml
    # `hubctl up --mode sim` leaves a type without a simulator emulated
    assert effective_mode("cnc_door", DeviceMode.EMULATE, DeviceMode.SIM) is DeviceMode.EMULATE


def test_a_station_type_parses_without_the_model() -> None:
    config = parse_config(example_text("shared_workspace"), str(example("shared_workspace")))
    assert config.device("vac_a").type == "vacuum_gripper" and config.device("vac_a").mode == "emulate"


def test_deploy_refuses_a_model_file_that_the_release_would_not_carry(capsys: pytest.CaptureFixture[str]) -> None:
    """An example's model is a file beside its hubs.toml: it runs locally, but a release (the wheel and hubs.toml)
    would not carry it to the Pi, so `hubctl deploy` says so before it touches anything."""
    assert hubctl(["deploy", "robot", "--dry-run", "--config", str(example("machine_tending"))]) == 1
    err = capsys.readouterr().err
    assert "station.model is the file" in err and "model.py" in err and "nothing on the target was changed" in err
