"""`hubctl replay`: a recorded run's inputs fed to a fresh controller core reproduce its decisions.

Every file in tests/replays/ is a trimmed recording (`hubctl replay RUN --save-test tests/replays/NAME`)
and must replay to the same decisions. The fault test records a station of processes over Zenoh
whose hub is killed with kill -9 mid-run, and replays that.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest

from common.config.hubs_toml import RecordingConfig
from common.stations import load_model
from controller.recording.hooks import open_recording
from controller.recording.reader import list_runs, open_run
from controller.recording.schema import CommandRecord, LivelinessRecord, RecordKind, RunMeta, RunMode, WatchdogRecord
from controller.recording.writer import RECORDING_DIR_ENV
from controller.timeline.model import build_timeline
from deploy.cli import main as hubctl
from deploy.local.inprocess import run_in_process
from deploy.replay.replay import Replayer
from tests.fault_station.checks import RUN_TIMEOUT_S, nr_running_on_bolt, op_states
from tests.fault_station.harness import Station

REPLAYS = Path(__file__).with_name("replays")
FAULT_MODEL = "tests.fault_station.model:build_model"


@pytest.mark.parametrize("path", sorted(REPLAYS.glob("*.sqlite")), ids=lambda p: p.stem)
def test_saved_run_replays_to_the_same_decisions(path: Path) -> None:
    with open_run(path) as run:
        result = Replayer(run).replay()
    assert result.same, str(result.divergence)
    assert result.decisions["command"] > 0 and result.decisions["plan"] > 0 and result.decisions["operation"] > 0


def record_in_process(directory: Path, seed: int = 2) -> Path:
    model = load_model(FAULT_MODEL)
    meta = RunMeta(station=model.name, model=FAULT_MODEL, mode=RunMode.IN_PROCESS, seed=seed,
                   budget={"first_expansions": 20_000, "improve_expansions": 0, "symbolic_layers": 500})
    recording = open_recording(RecordingConfig(dir=str(directory)), meta, model)
    assert recording is not None, "the run's recording could not be opened"
    summary = run_in_process(model, seed=seed, failure={"nr": 0.3}, recording=recording)
    assert summary.finished
    return recording.path


def test_in_process_run_replays_with_its_plans_planned_again(tmp_path: Path) -> None:
    path = record_in_process(tmp_path)
    with open_run(path) as run:
        assert run.meta.outcome == "finished" and run.meta.operations_done == run.meta.operations_total == 4
        result = Replayer(run).replay()
    assert result.same, str(result.divergence)
    assert result.decisions["plan"] >= 1 and result.decisions["command"] > 4


def test_a_changed_decision_is_reported_as_the_first_diverging_event(tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    path = record_in_process(tmp_path)
    with sqlite3.connect(path) as db:  # the recording says the 3rd command went out with other values
        row, data = db.execute("SELECT id, data FROM events WHERE kind = 'command' ORDER BY id LIMIT 1 OFFSET 2"
                               ).fetchone()
        command = msgspec.msgpack.decode(data, type=CommandRecord)
        path_changed, value = next(iter(command.values.items()))
        changed = {**command.values, path_changed: "other" if isinstance(value, str) else not value}
        db.execute("UPDATE events SET data = ? WHERE id = ?",
                   (msgspec.msgpack.encode(CommandRecord(values=changed, seq=command.seq)), row))
        t, resource = db.execute("SELECT t, key FROM events WHERE id = ?", (row,)).fetchone()

    assert hubctl(["replay", str(path)]) == 1
    out = capsys.readouterr().out
    assert f"first diverging event at t={t:.3f} s: command {resource}" in out
    assert f"recorded: {changed} seq {command.seq}" in out and f"replayed: {command.values} seq {command.seq}" in out
    assert hubctl(["replay", str(path), "--save-test", str(tmp_path / "saved")]) == 1
    assert not (tmp_path / "saved.sqlite").exists()


@pytest.fixture
def recorded_station(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Station]:
    monkeypatch.setenv(RECORDING_DIR_ENV, str(tmp_path / "runs"))  # the controller process inherits it
    with Station(tmp_path) as station:
        yield station


def test_hub_killed_mid_run_recording_replays_to_the_same_decisions(recorded_station: Station,
                                                                     tmp_path: Path) -> None:
    station = recorded_station
    station.start()
    nr_running_on_bolt(station, 2)
    station.kill("pi-tool")
    station.wait_for(lambda: (h := station.watch.health("nr")) is not None and "not alive" in h.reason, 5,
                     "nr reported unhealthy: hub not alive")
    station.start_hub("pi-tool")
    station.wait_for(station.watch.finished, RUN_TIMEOUT_S, "the station finishes after the hub restart")
    station.close()  # SIGTERM: the controller closes its recording

    (info,) = list_runs(tmp_path / "runs")
    assert info.meta.mode == "service" and info.meta.outcome == "finished" and info.meta.operations_done == 4
    with open_run(info.path) as run:
        (gone,) = [r.t for r in run.events(kinds=[RecordKind.LIVELINESS], key="pi-tool")
                   if not r.data_as(LivelinessRecord).alive]
        verdicts = [(r.t, r.data_as(WatchdogRecord).verdict)
                    for r in run.events(kinds=[RecordKind.WATCHDOG], key="nr", since=gone)]
        result = Replayer(run).replay()
        timeline = build_timeline(run)
    # The unhealthy span: from the hub's token vanishing until the restarted hub's states come.
    assert [verdict for _, verdict in verdicts] == ["unhealthy", "recovered"], verdicts
    # ... and the timeline (hubctl timeline) shades it on nr's lane.
    assert [(p.start, p.end) for p in timeline.unhealthy if p.lane == "nr" and p.start >= gone] == [
        (verdicts[0][0], verdicts[1][0])]
    assert result.same, str(result.divergence)
    assert result.decisions["command"] > 8 and result.decisions["plan_request"] >= 2


@pytest.mark.slow
def test_controller_killed_and_restarted_on_its_database_both_runs_replay(recorded_station: Station,
                                                                          tmp_path: Path) -> None:
    station = recorded_station
    station.start()
    station.wait_for(lambda: (s := station.watch.status()) is not None and "finished" in op_states(s).values(),
                     RUN_TIMEOUT_S, "an operation finished")
    station.kill("controller")
    station.start_controller(fresh=False)  # restores from its database, takes the hubs' mirrors
    station.wait_for(station.watch.finished, RUN_TIMEOUT_S, "the station finishes after the controller restart")
    station.close()

    first, second = list_runs(tmp_path / "runs")
    assert first.meta.outcome == "running" and second.meta.outcome == "finished"  # killed: never closed
    for info in (first, second):
        with open_run(info.path) as run:
            loaded = list(run.events(kinds=[RecordKind.RESTORE]))
            result = Replayer(run).replay()
        assert result.same, f"{info.path}: {result.divergence}"
    assert len(loaded) >= 2  # the second run loaded its persisted state and the hubs' mirrors
