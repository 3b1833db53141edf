"""Properties of random stations with timing (issue 21, item 6): robots, grippers and feeders whose sensors race them.

Stations come from `tests.stations.random_timed_station.build_random_timed_station(seed, followable=...)`.
Followable ones (a plan the devices can follow exists, whatever the effects' timing within their intervals)
must all complete in process; unfollowable ones (each robot's own program leaves a feeder before its sensor
can register) must stop within a minute of station time with the `Livelock` diagnosis and their operations
in error, never asking for the same goals from one state more than `GIVE_UP_AFTER` times. A sample of
followable ones runs as processes over Zenoh. A failure names the seed that rebuilds the station, what was
drawn, and the run's last events.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from common.model import OperationState
from controller.livelock import GIVE_UP_AFTER
from controller.synthesis import synthesize
from deploy.local.inprocess import RunSummary, run_in_process
from deploy.local.station import Options, run_station
from tests.stations.random_timed_station import (
    SensorTiming,
    Shape,
    build_random_timed_station,
    build_random_timed_station_with_shape,
)
from tests.timing_stations.recorded import Recorded

SEEDS = st.integers(min_value=0, max_value=2**31 - 1)
ROOT = Path(__file__).resolve().parent.parent
FOLLOWABLE_TIME_LIMIT = 300.0  # station seconds: a followable station takes a few
STOPS_WITHIN = 60.0  # station seconds in which an unfollowable one must have stopped, the diagnosis said
LAST_EVENTS_SHOWN = 15
# A seed is not made simpler by shrinking it: the failing one is the example, as drawn. The seeds are drawn
# the same way in every run (derandomize): the suite checks one fixed sample, which a failure names.
RUN_ONLY = (Phase.explicit, Phase.reuse, Phase.generate)


def run(seed: int, *, followable: bool, time_limit: float) -> tuple[Shape, RunSummary, Recorded]:
    model, shape = build_random_timed_station_with_shape(seed, followable=followable)
    recorded = Recorded()
    summary = run_in_process(model, seed=seed, time_limit=time_limit, recording=recorded)
    return shape, summary, recorded


def explain(seed: int, followable: bool, shape: Shape, summary: RunSummary) -> str:
    return (f"build_random_timed_station({seed}, followable={followable}): {shape.describe()}\n"
            f"{summary.operations_finished}/{summary.operations_total} operations in {summary.emulated_seconds:.1f} "
            f"station seconds, {summary.plans} plans: {summary.reason}\nlast events:\n  "
            + "\n  ".join(summary.log[-LAST_EVENTS_SHOWN:]))


def check_followable_completes(seed: int) -> None:
    shape, summary, recorded = run(seed, followable=True, time_limit=FOLLOWABLE_TIME_LIMIT)
    assert summary.finished, explain(seed, True, shape, summary)
    assert not recorded.livelocks(), explain(seed, True, shape, summary)
    # The run is itself a schedule of its work with its causes under the supervisor, its effects drawn within their
    # durations: no bound may exceed it (the specifications' exclusions made the bound in 54 of 80 seeds).
    cycle = summary.cycle
    assert cycle is not None
    assert cycle.bound <= cycle.cycle + 1e-9, (cycle.lines(), explain(seed, True, shape, summary))
    assert recorded.most_requests_from_one_state() <= GIVE_UP_AFTER, explain(seed, True, shape, summary)


def check_unfollowable_stops_with_the_diagnosis(seed: int) -> None:
    shape, summary, recorded = run(seed, followable=False, time_limit=3600.0)
    said = explain(seed, False, shape, summary)
    assert not summary.finished and summary.operations_finished == 0, said
    assert summary.reason.startswith("stuck") and summary.emulated_seconds < STOPS_WITHIN, said
    livelocks = recorded.livelocks()
    assert livelocks, said
    # Mostly the diagnosis names the feeder's sensor that never registered; now and then the goals are given up
    # after GIVE_UP_AFTER requests with no lost effect known (e.g. seed 192351): a Livelock either way.
    assert all(t < STOPS_WITHIN for t, _ in livelocks), (livelocks, said)
    in_error = {name for name, state in recorded.final_states().items() if state is OperationState.ERROR}
    assert in_error == {f"Place{i}" for i in range(1, len(shape.boxes) + 1)}, said
    assert in_error <= {op for _, livelock in livelocks for op in livelock.operations}, (livelocks, said)
    assert recorded.most_requests_from_one_state() <= GIVE_UP_AFTER, said


@settings(max_examples=50, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow],
          phases=RUN_ONLY)
@given(seed=SEEDS)
def test_followable_timed_stations_complete_in_process(seed: int) -> None:
    check_followable_completes(seed)


@pytest.mark.slow
@settings(max_examples=500, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow],
          phases=RUN_ONLY)
@given(seed=SEEDS)
def test_500_followable_timed_stations_complete_in_process(seed: int) -> None:
    check_followable_completes(seed)


# Each unfollowable station costs seconds of wall time: every request is checked in time and searched again
# with the learnt races before the livelock watch gives up; a few in the default run, more among the slow ones.
@settings(max_examples=5, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow],
          phases=RUN_ONLY)
@given(seed=SEEDS)
def test_unfollowable_timed_stations_stop_within_a_minute_with_the_diagnosis(seed: int) -> None:
    check_unfollowable_stops_with_the_diagnosis(seed)


@pytest.mark.slow
@settings(max_examples=40, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow],
          phases=RUN_ONLY)
@given(seed=SEEDS)
def test_40_unfollowable_timed_stations_stop_with_the_diagnosis(seed: int) -> None:
    check_unfollowable_stops_with_the_diagnosis(seed)


@settings(max_examples=100, deadline=None)
@given(seed=SEEDS, followable=st.booleans())
def test_timed_stations_are_valid_reproducible_and_timed_as_drawn(seed: int, followable: bool) -> None:
    model, shape = build_random_timed_station_with_shape(seed, followable=followable)
    synthesize(model)  # its specifications can be met from the initial state
    again = build_random_timed_station(seed, followable=followable)
    assert [str(t) for t in again.transitions] == [str(t) for t in model.transitions]
    assert [r.duration for r in again.resources] == [r.duration for r in model.resources]
    assert all(f.timing.followable is followable for f in shape.feeders)
    for feeder in shape.feeders:
        sensor = shape.durations[feeder.name]
        quickest_leave = min(shape.durations[r].min_s for r in feeder.robots)
        slowest_leave = max(shape.durations[r].max_s for r in feeder.robots)
        if feeder.timing is SensorTiming.FASTER:
            assert sensor.max_s < quickest_leave
        else:  # the race: a robot sent on at once always leaves before the sensor registers
            assert sensor.min_s > slowest_leave
    assert {f.timing for f in shape.feeders} <= (
        {t for t in SensorTiming if t.followable} if followable else {SensorTiming.UNAVOIDABLE})


ZENOH_SEEDS = (2, 10, 11)  # three robots on one feeder; a guarded shared feeder and a race; a shared race


@pytest.mark.slow
@pytest.mark.parametrize("seed", ZENOH_SEEDS)
async def test_followable_timed_stations_complete_as_processes_over_zenoh(
        seed: int, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`hubctl up` on a generated station: real hubs whose emulated effects come at their own times."""
    monkeypatch.chdir(ROOT)  # the model module imports the generator from this repository
    model, shape = build_random_timed_station_with_shape(seed)
    config = write_station(tmp_path, seed, model.resources)
    lines: list[str] = []
    options = Options(config=str(config), speed=1.0, run_dir=tmp_path / "run", time_limit=120.0)
    code = await run_station(options, say=lines.append)
    output = "\n".join(lines)
    assert code == 0, f"{shape.describe()}\n{output[-3000:]}"
    assert f"finished: {len(model.operations)}/{len(model.operations)} operations" in output, output[-3000:]


def write_station(directory: Path, seed: int, resources: Any) -> Path:
    """hubs.toml for the station of `seed`, one hub per device, every device emulated, next to its model module."""
    (directory / "model.py").write_text(
        "from tests.stations.random_timed_station import build_random_timed_station\n\n\n"
        f"def build_model():\n    return build_random_timed_station({seed})\n")
    hubs = "".join(
        f'\n[hubs.{r.name}]\nhost = "localhost"\n\n[hubs.{r.name}.devices.{r.name}]\n'
        f'type = "{r.device_type}"\nmode = "emulate"\n' for r in resources)
    config = directory / "hubs.toml"
    config.write_text(f"""[station]
name = "random_timed_{seed}"
model = "model.py:build_model"

[network]
mode = "peer"
connect = []
listen = []
lease_ms = 2000

[controller]
host = "localhost"
name = "ctl"
command_rate_hz = 10
tick_rate_hz = 20
db = "{directory / 'controller.sqlite'}"
mirror_timeout_s = 1.0
stale_after_s = 0.5
{hubs}""")
    return config
