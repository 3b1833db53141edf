"""Plans the devices can follow (issue 21): the engine holds a command that would overtake an effect due on the
measured state, and the controller notices when it goes round in circles. Run in process, in virtual time, on
the feeder station of tests/timing_stations/feeder.py."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.model import OperationState
from common.wire.ctl import Livelock
from controller.livelock import RETRIES as LIVELOCK_RETRIES
from deploy.local.inprocess import run_in_process
from deploy.local.station import Options, run_station
from tests.timing_stations.feeder import build_model
from tests.timing_stations.recorded import Recorded

ONE_HOUR = 3600.0
ROOT = Path(__file__).resolve().parent.parent


def test_feeder_station_completes_in_process_the_robot_waiting_for_the_sensor() -> None:
    # On main 57f0ca4 it planned 12,000 times in the emulated hour, round and round the same states.
    recorded = Recorded()
    summary = run_in_process(build_model(), time_limit=60.0, recording=recorded)
    assert summary.finished, (summary.reason, summary.log[-5:])
    assert summary.replans == 0 and summary.emulated_seconds < 2.0
    assert recorded.most_requests_from_one_state() == 1


def test_a_race_no_plan_avoids_stops_with_the_diagnosis_within_a_minute_of_station_time() -> None:
    recorded = Recorded()
    summary = run_in_process(build_model(unavoidable=True), time_limit=ONE_HOUR, recording=recorded)
    assert not summary.finished
    livelocks = [(t, e) for t, e in recorded.events if isinstance(e, Livelock)]
    assert len(livelocks) == 1, livelocks  # said once, not at every retry
    said_at, livelock = livelocks[0]
    assert said_at < 60.0
    assert livelock.operations == ["Place"] and livelock.effect == "f.taken.effect"
    assert livelock.diagnosis == ("f.present_m never became false (f.taken.effect): r.pos_m left at_feeder "
                                  "(now unknown) after r.leave_when_gripped")
    assert any(line.startswith("livelock: f.present_m never became false") for line in summary.log)
    # In error from the diagnosis on, retried with backoff, then left to the operator: nothing more is planned
    # after the first minute, and the run ends there, stuck with the operation in error.
    to_error = [t for t, _, change in recorded.operations if change.after == OperationState.ERROR]
    retried = [t for t, _, change in recorded.operations if change.before == OperationState.ERROR]
    assert to_error[0] == said_at and len(retried) == LIVELOCK_RETRIES == len(to_error) - 1
    assert recorded.operations[-1][2].after == OperationState.ERROR
    assert recorded.requests[-1][0] < 60.0
    assert summary.reason.startswith("stuck") and summary.emulated_seconds < 60.0
    assert recorded.most_requests_from_one_state() <= 20


@pytest.mark.slow
async def test_the_feeder_station_completes_as_processes_over_zenoh(tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """`hubctl up --config tests/timing_stations/hubs.toml`: the race of issue 21 on real hubs, whose emulated
    effects come at their own times, not when the controller asks."""
    monkeypatch.chdir(ROOT)
    lines: list[str] = []
    options = Options(config=str(ROOT / "tests" / "timing_stations" / "hubs.toml"), speed=1.0, run_dir=tmp_path,
                      time_limit=120.0)
    code = await run_station(options, say=lines.append)
    output = "\n".join(lines)
    assert code == 0, output[-3000:]
    assert "finished: 1/1 operations" in output, output[-3000:]
