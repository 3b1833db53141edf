"""The order of a plan's steps is a setting: `[controller] execution` of hubs.toml, `--execution` of `hubctl up`
(in process and over processes) and of the controller. The engine runs plans in it, the recording says which
it was (RunMeta.execution, PlanRecord.execution when the timed check chose), and a replay follows it."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.config.hubs_toml import load_config
from common.config.modes import DEFAULT_EXECUTION, Execution
from controller.recording.reader import list_runs, open_run
from controller.recording.schema import PlanAnswer, PlanRecord, RecordKind, RunMode
from controller.recording.writer import RECORDING_DIR_ENV
from deploy.cli import main as hubctl
from deploy.local.station import Options, child_commands
from deploy.replay.replay import Replayer
from tests.fault_station.checks import RUN_TIMEOUT_S
from tests.fault_station.harness import TEMPLATE, Station

FAULT_CONFIG = TEMPLATE  # tests/fault_station/hubs.toml: two emulated hubs, four bolts
SHARED_WORKSPACE = Path(__file__).resolve().parent.parent / "examples" / "shared_workspace" / "hubs.toml"
CONTROLLER_KEY = "stale_after_s = 0.5\n"  # the last line of its [controller] table


def with_execution(directory: Path, execution: Execution) -> Path:
    """The fault station's hubs.toml with `[controller] execution` set."""
    text = FAULT_CONFIG.read_text()
    assert CONTROLLER_KEY in text
    path = directory / "hubs.toml"
    path.write_text(text.replace(CONTROLLER_KEY, f'{CONTROLLER_KEY}execution = "{execution}"\n', 1))
    return path


def recorded_run(directory: Path) -> Path:
    (info,) = list_runs(directory)
    return info.path


def test_the_default_is_the_trace() -> None:
    assert load_config(FAULT_CONFIG).controller.execution is DEFAULT_EXECUTION is Execution.TRACE


@pytest.mark.parametrize("execution", list(Execution))
def test_hubs_toml_chooses_the_order(tmp_path: Path, execution: Execution) -> None:
    assert load_config(with_execution(tmp_path, execution)).controller.execution is execution


def test_hubctl_up_passes_its_execution_to_the_controller_process(tmp_path: Path) -> None:
    config = load_config(FAULT_CONFIG)
    options = Options(config=str(FAULT_CONFIG), run_dir=tmp_path, execution=Execution.SEQUENCE)
    controller, *hubs = child_commands(config, options, port=7447)
    assert controller.name == "controller"
    at = controller.argv.index("--execution")
    assert controller.argv[at + 1] == "sequence"
    assert all("--execution" not in hub.argv for hub in hubs)
    (default_controller, *_) = child_commands(config, Options(config=str(FAULT_CONFIG), run_dir=tmp_path), port=7447)
    assert "--execution" not in default_controller.argv  # the controller reads hubs.toml's then


@pytest.mark.parametrize(("in_file", "flag", "runs_in"), [
    (Execution.PARTIAL_ORDER, "sequence", Execution.SEQUENCE),
    (Execution.TRACE, None, Execution.TRACE),
])
def test_hubctl_up_in_process_runs_and_records_the_chosen_order_and_replays_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
        in_file: Execution, flag: str | None, runs_in: Execution) -> None:
    monkeypatch.setenv(RECORDING_DIR_ENV, str(tmp_path / "runs"))
    config = with_execution(tmp_path, in_file)
    argv = ["up", "--in-process", "--config", str(config), "--seed", "1"]
    assert hubctl(argv + (["--execution", flag] if flag else [])) == 0
    assert f"plans in {runs_in}" in capsys.readouterr().out
    with open_run(recorded_run(tmp_path / "runs")) as run:
        assert run.meta.mode == RunMode.IN_PROCESS and run.meta.execution is runs_in
        replayed = Replayer(run).replay()
    assert replayed.same, str(replayed.divergence)


def test_a_replay_runs_the_recorded_order_not_the_default(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two robots sharing a fixture's zone (examples/shared_workspace) run in the trace, replayed in the
    partial order instead, decide otherwise (the robots overlap more): the replay must take the order from the
    recording."""
    monkeypatch.setenv(RECORDING_DIR_ENV, str(tmp_path / "runs"))
    assert hubctl(["up", "--in-process", "--config", str(SHARED_WORKSPACE), "--execution", "trace"]) == 0
    path = recorded_run(tmp_path / "runs")
    with open_run(path) as run:
        assert Replayer(run).replay().same
        run.meta.execution = Execution.PARTIAL_ORDER
        assert not Replayer(run).replay().same


@pytest.mark.timeout(180)
def test_the_live_controller_runs_its_plans_in_the_partial_order_hubs_toml_chooses(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """Over processes: the first plan goes out in sequence, the planner process's verdict loosens it to the
    controller's own order, the partial order of hubs.toml (the default is the trace)."""
    monkeypatch.setenv(RECORDING_DIR_ENV, str(tmp_path / "runs"))  # the controller process inherits it
    with Station(tmp_path, replace=[(CONTROLLER_KEY, f'{CONTROLLER_KEY}execution = "partial_order"\n')]) as station:
        assert station.config.controller.execution is Execution.PARTIAL_ORDER
        station.start()
        station.wait_for(station.watch.finished, RUN_TIMEOUT_S, "the station finishes")
        station.close()  # SIGTERM: the controller closes its recording
    with open_run(recorded_run(tmp_path / "runs")) as run:
        assert run.meta.execution is Execution.PARTIAL_ORDER
        plans = [r.data_as(PlanRecord) for r in run.events(kinds=[RecordKind.PLAN])]
        replayed = Replayer(run).replay()
    assert any(p.answer == PlanAnswer.CHECKED and p.taken and p.execution == Execution.PARTIAL_ORDER
               for p in plans), plans
    assert replayed.same, str(replayed.divergence)
