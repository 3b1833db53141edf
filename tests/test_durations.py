"""Durations in the model: from the standard types, a station's own types and hubs.toml's `delay`; the
emulator picks a time within the interval; `hubctl plan` shows them with the predicted makespan."""

from __future__ import annotations

import math
import random
from pathlib import Path

import pytest

from common.config.hubs_toml import ConfigError, parse_config
from common.model import Duration, Model
from common.model.durations import FALLBACK, DurationSource
from common.resources import TYPE_DURATIONS, durations_of
from common.stations import engine_assembly, load_model
from controller.makespan import earliest_schedule, makespan
from deploy.cli import main
from hubs.emulator import EffectEmulator
from tests.stations.timing import VACUUM_DURATION, feeder_station

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"

# The emulated delays of the standard types before durations were in the model (hubs/emulator.py's
# DEFAULT_DELAYS): recorded runs replay only if they stay the same.
DELAYS_BEFORE = {"nutrunner": 0.12, "ur": 0.15, "rsp": 0.15, "dock": 0.1, "lift": 0.3, "mir": 0.8, "agv": 0.8,
                 "rfid": 0.4, "camera": 0.1, "operator": 0.5}

CONFIG = """\
[station]
name = "demo"
model = "common.stations.engine_assembly:build_model"

[controller]
host = "decs"

[hubs.cell]
host = "cell"

[hubs.cell.devices.nr]
type = "nutrunner"
delay = {nr}

[hubs.cell.devices.ur]
type = "ur"
delay = {ur}
"""


def config_with(nr: str = "0.5", ur: str = "[0.1, 0.3]") -> str:
    return CONFIG.format(nr=nr, ur=ur)


def test_every_standard_type_declares_the_delay_it_emulated_with() -> None:
    assert {t: (d.min_s, d.max_s) for t, d in TYPE_DURATIONS.items()} == {t: (s, s) for t, s in DELAYS_BEFORE.items()}
    table = durations_of(engine_assembly.build_model())
    for entry in table.entries:
        assert entry.source is DurationSource.DEVICE_TYPE
        assert entry.duration == Duration.fixed(DELAYS_BEFORE[entry.device_type])


def test_a_station_type_declares_its_own_and_one_that_does_not_gets_the_fallback() -> None:
    table = durations_of(feeder_station())
    assert table.entry("g").duration == VACUUM_DURATION
    assert table.entry("g").source is DurationSource.RESOURCE
    assert table.entry("f").duration == FALLBACK
    assert table.entry("f").source is DurationSource.FALLBACK
    assert table.entry("r").source is DurationSource.DEVICE_TYPE
    # the older spelling, `parameters["emulated_delay"]`, is the same declaration
    tending = load_model(f"{EXAMPLES / 'machine_tending' / 'model.py'}:build_model")
    assert durations_of(tending).entry("door").duration == Duration.fixed(0.4)
    assert durations_of(tending).entry("door").source is DurationSource.RESOURCE


def test_hubs_toml_delay_is_a_fixed_time_or_an_interval() -> None:
    config = parse_config(config_with())
    assert config.delays == {"nr": Duration.fixed(0.5), "ur": Duration(0.1, 0.3)}
    assert config.device("nr").params == {}  # `delay` is the emulation's, not a driver parameter
    table = durations_of(engine_assembly.build_model(), config.delays)
    assert table.entry("ur").duration == Duration(0.1, 0.3)
    assert table.entry("ur").source is DurationSource.CONFIG
    assert table.entry("nr").duration == Duration.fixed(0.5)
    assert table.entry("rsp").source is DurationSource.DEVICE_TYPE


@pytest.mark.parametrize(("value", "fragment"), [
    ('"fast"', "expected seconds (a number) or an interval [min, max], found a string 'fast'"),
    ("-1", "not negative"),
    ("[0.3, 0.1]", "min (0.3 s) is above its max (0.1 s)"),
    ("[0.1]", "an interval is [min, max], two numbers: found 1 item(s)"),
    ('[0.1, "x"]', "expected seconds, a number, found a string 'x'"),
    ("true", "found a boolean True"),
    ("inf", "finite"),
])
def test_a_bad_delay_names_file_line_and_key(value: str, fragment: str) -> None:
    text = config_with(ur=value)
    with pytest.raises(ConfigError) as caught:
        parse_config(text, "station.toml")
    [problem] = caught.value.problems
    assert problem.file == "station.toml"
    assert problem.key == "hubs.cell.devices.ur.delay"
    assert problem.line == text.splitlines().index(f"delay = {value}") + 1
    assert fragment in problem.message


def test_a_duration_is_an_interval_of_seconds() -> None:
    assert str(Duration(0.1, 0.3)) == "0.1-0.3 s" and str(Duration.fixed(2)) == "2 s"
    for low, high in ((-1.0, 1.0), (2.0, 1.0), (math.nan, 1.0), (0.0, math.inf)):
        with pytest.raises(ValueError):
            Duration(low, high)


def emulator(model: Model, seed: int, **kwargs: object) -> EffectEmulator:
    return EffectEmulator(model, (r.name for r in model.resources), seed=seed, **kwargs)  # type: ignore[arg-type]  # the test passes the emulator's keywords through


def test_the_emulator_picks_within_the_interval_reproducibly_by_seed() -> None:
    model = engine_assembly.build_model()
    move = model.transition_by_name["ur.move_to_home.starting.effect"]

    def picks(seed: int, speed: float = 1.0) -> list[float]:
        emulated = emulator(model, seed, delays={"ur": Duration(0.1, 0.3)}, speed=speed)
        return [emulated.delay_of(move) for _ in range(200)]

    first = picks(seed=7)
    assert all(0.1 <= delay <= 0.3 for delay in first)
    assert max(first) - min(first) > 0.15  # spread over the interval, not one value
    assert picks(seed=7) == first
    assert picks(seed=8) != first
    assert all(0.05 <= delay <= 0.15 for delay in picks(seed=7, speed=2.0))


def test_a_fixed_duration_draws_nothing_from_the_emulators_random() -> None:
    model = engine_assembly.build_model()
    emulated = emulator(model, seed=3, speed=2.0)
    before = emulated.random.getstate()
    for effect in emulated.effects:
        owner_type = model.resource_by_name[next(iter(effect.written())).split(".")[0]].device_type
        assert emulated.delay_of(effect) == DELAYS_BEFORE[owner_type] / 2.0
    assert emulated.random.getstate() == before
    assert emulated.random.random() == random.Random(3).random()


def test_the_earliest_schedule_runs_independent_effects_at_once_and_puts_off_a_racing_command() -> None:
    model = feeder_station()
    table = durations_of(model)
    steps = [model.transition_by_name[name] for name in (
        "r.move_to_at_feeder.enabled", "r.move_to_at_feeder.starting.effect", "g.grip.enabled",
        "r.move_to_at_feeder.executing.effect", "r.move_to_at_pallet.enabled", "g.grip.starting.effect",
        "f.taken.executing.effect", "cell.box_held", "r.move_to_at_pallet.starting.effect",
        "r.move_to_at_pallet.executing.effect")]
    schedule = {s.transition: s for s in earliest_schedule(steps, table)}
    assert schedule["g.grip.starting.effect"].start_s == 0.0  # the gripper sucks while the robot moves
    assert schedule["f.taken.executing.effect"].start_s == pytest.approx(0.3)  # robot there (0.15 s x 2)
    # the plan sends the robot on before the feeder's sensor is done: the command waits for it
    assert schedule["r.move_to_at_pallet.enabled"].start_s == pytest.approx(0.5)
    assert makespan(tuple(schedule.values())) == pytest.approx(0.8)


def test_hubctl_plan_prints_the_durations_and_the_predicted_makespan(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["plan", "--model", "tests.stations.timing:feeder_station", "Place"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    start = lines.index("durations planned with (per resource: type, seconds, declared by):")
    assert [line.split() for line in lines[start + 1:start + 4]] == [
        ["r", "ur", "0.15", "s", "its", "device", "type"],
        ["g", "vacuum_gripper", "0.1", "s", "the", "resource's", "model"],
        ["f", "box_feeder", "0.2", "s", "fallback:", "its", "type", "declares", "none"],
    ]
    assert "predicted makespan: 0.80 s with each step as early as its causal order allows" in out
    assert "(1.00 s one step after another)" in out


def test_hubctl_plan_takes_the_delays_of_hubs_toml(capsys: pytest.CaptureFixture[str]) -> None:
    config = EXAMPLES / "machine_tending" / "hubs.toml"
    assert main(["plan", "--config", str(config), "cnc.clamped_m"]) == 0
    out = capsys.readouterr().out
    cnc = next(line for line in out.splitlines() if line.strip().startswith("cnc "))
    assert cnc.split()[2:] == ["0.5", "s", "hubs.toml", "delay"]


def test_the_operators_button_release_takes_its_own_time_whatever_a_task_takes() -> None:
    from common.model.compiled import CompiledModel
    from common.model.durations import duration_in
    from controller.timed_check import corner_timings

    model = load_model()
    table = durations_of(model, {"human": Duration.fixed(20.0)})
    by_name = {t.name: t for t in model.ability_transitions}
    task, release = by_name["human.mount_filter1.executing.effect"], by_name["human.release_button.resetting.effect"]
    assert table.of_transition(task) == Duration.fixed(20.0)
    assert table.of_transition(release) == Duration.fixed(0.5)
    keyed = table.keyed()
    assert duration_in(keyed, task.name, "human") == Duration.fixed(20.0)
    assert duration_in(keyed, release.name, "human") == Duration.fixed(0.5)
    # The emulator and the timed check read the same.
    emulator = EffectEmulator(model, ["human"], delays={"human": 20.0})
    assert emulator.durations.of_transition(release) == Duration.fixed(0.5)
    timings = corner_timings(CompiledModel(model), keyed)
    assert {timing.seconds[release.name] for timing in timings} == {0.5}
    assert {timing.seconds[task.name] for timing in timings} == {20.0}


def test_a_duration_declared_for_an_ability_the_resource_lacks_is_refused_with_its_name() -> None:
    from common.resources import operator

    human = operator("human", tasks=("wave",))
    wrong = type(human)(human.name, human.variables, human.abilities, human.device_type,
                        ability_durations={"wink": Duration.fixed(1.0)})
    with pytest.raises(KeyError, match=r"'human'.*wink"):
        durations_of(Model("m", (wrong,)))
