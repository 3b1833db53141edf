"""`hubctl up` supervises its processes as systemd does on the cell, and `--chaos N` (issue 22, item 4).

The fast tests check the parts alone: the restart policy the units and `up` share, systemd's start
window, the chaos plan from a seed, the supervisor with small real processes, and the "each
operation done once" count over recordings. The slow ones run tests/fault_station (a robot, a
nutrunner, 4 bolts: ~5 s) with `run_station`, the controller and both hubs as processes over Zenoh
on loopback, kill some of them with SIGKILL and check from the run's recordings that every bolt was
tightened once and every operation finished once.
"""

from __future__ import annotations

import asyncio
import signal
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from common.config.hubs_toml import load_station
from common.model import OperationState
from controller.recording.reader import Record, open_run
from controller.recording.schema import OperationRecord, RecordKind, RestoreRecord, StateRecord
from deploy.cli import main as hubctl
from deploy.local import station as station_module
from deploy.local.chaos import Chaos, ChaosPlan, Kill, plan_chaos
from deploy.local.done_once import DoneOnce, count_finishes, run_recordings
from deploy.local.station import Options, run_station
from deploy.local.supervisor import Child, StartWindow, Supervisor, describe_exit
from deploy.remote.restart_policy import GROWING_RESTART, UP_RESTART, RestartPolicy, StartLimit
from tests.fault_station.harness import ROOT, write_config
from tests.fault_station.model import BOLT_POSES, BOLTS

FAST_RESTART = RestartPolicy(delay_s=0.1, steps=2, max_delay_s=0.3, start_limit=StartLimit(interval_s=30.0, burst=3))


# --- the restart policy and systemd's start window ------------------------------------------------

def test_the_delay_grows_from_restart_sec_to_the_max_over_the_steps_as_systemd_computes_it() -> None:
    delays = [GROWING_RESTART.delay(n) for n in range(1, 9)]
    assert delays[0] == 1.0 and delays[6:] == [60.0, 60.0]
    assert delays[1] == pytest.approx(60 ** (1 / 6)) and delays[5] == pytest.approx(60 ** (5 / 6))
    assert delays == sorted(delays)
    assert RestartPolicy(delay_s=5.0).delay(4) == 5.0


def test_up_restarts_as_the_units_do_with_a_start_limit_added() -> None:
    assert UP_RESTART.service_lines() == GROWING_RESTART.service_lines() == [
        "Restart=always", "RestartSec=1s", "RestartSteps=6", "RestartMaxDelaySec=60s"]
    assert GROWING_RESTART.unit_lines() == ["StartLimitIntervalSec=0"]
    assert UP_RESTART.unit_lines() == ["StartLimitIntervalSec=120s", "StartLimitBurst=5"]


def test_start_window_allows_burst_starts_within_its_interval_then_begins_again() -> None:
    window = StartWindow(StartLimit(interval_s=10.0, burst=3))
    assert [window.allow(t) for t in (0.0, 1.0, 2.0, 3.0)] == [True, True, True, False]
    assert window.allow(10.5)  # a new window begins after the interval
    assert StartWindow(None).allow(0.0) and all(StartWindow(None).allow(t) for t in range(100))


def test_exit_statuses_are_said_as_systemd_says_them() -> None:
    assert describe_exit(3) == "status 3"
    assert describe_exit(-signal.SIGKILL) == "killed by SIGKILL"


# --- the chaos plan --------------------------------------------------------------------------------

PROCESSES = ["controller", "pi-tool", "pi-rsp", "ur10", "rfidcam"]


def test_the_same_seed_gives_the_same_chaos_plan() -> None:
    plan = plan_chaos(7, 1, PROCESSES, 45)
    assert plan == plan_chaos(7, 1, PROCESSES, 45)
    assert plan != plan_chaos(7, 2, PROCESSES, 45)
    assert len(plan.kills) == 7
    moments = [(k.after_operations, k.delay_s) for k in plan.kills]
    assert moments == sorted(moments)
    assert all(0 <= k.after_operations <= 43 and 0 <= k.delay_s <= 1.0 for k in plan.kills)


def test_chaos_kills_every_process_once_before_any_twice() -> None:
    for seed in range(20):
        victims = [k.victim for k in plan_chaos(7, seed, PROCESSES, 45).kills]
        counts = {p: victims.count(p) for p in PROCESSES}
        assert set(counts.values()) == {1, 2}, (seed, counts)
    assert plan_chaos(3, 0, ["controller"], 1).kills == tuple(
        Kill("controller", 0, k.delay_s) for k in plan_chaos(3, 0, ["controller"], 1).kills)
    with pytest.raises(ValueError, match="cannot be negative"):
        plan_chaos(-1, 0, PROCESSES, 45)


def test_chaos_needs_the_station_as_processes(capsys: pytest.CaptureFixture[str]) -> None:
    assert hubctl(["up", "--in-process", "--chaos", "2"]) == 2
    assert "--chaos kills processes" in capsys.readouterr().err
    assert hubctl(["up", "--chaos", "-1"]) == 2
    assert "--chaos -1: the number of kills cannot be negative" in capsys.readouterr().err


def test_chaos_kills_once_its_moment_comes_and_waits_for_a_victim_being_restarted() -> None:
    now = [0.0]
    running = {"pi-tool": True}
    killed: list[str] = []

    def kill(name: str) -> int | None:
        if not running[name]:
            return None
        killed.append(name)
        return 4242

    lines: list[str] = []
    chaos = Chaos(ChaosPlan(1, (Kill("pi-tool", 2, 0.5),)), kill, lines.append, lambda: now[0])
    chaos.observe(None)
    chaos.observe(1)
    now[0] = 5.0
    chaos.observe(2)  # reached now: due half a second later
    assert killed == []
    now[0] = 5.6
    running["pi-tool"] = False
    chaos.observe(2)
    assert killed == [] and chaos.pending
    running["pi-tool"] = True
    chaos.observe(2)
    assert killed == ["pi-tool"] and not chaos.pending
    assert "CHAOS  kill -9 pi-tool (pid 4242), 1 of 1" in lines[0]
    assert chaos.summary() == "chaos (seed 1): 1 of 1 kills done"


# --- each operation done once, from the records ---------------------------------------------------

INITIAL, EXECUTING, FINISHED = OperationState.INITIAL, OperationState.EXECUTING, OperationState.FINISHED


def _op(key: str, before: OperationState, after: OperationState) -> Record:
    return Record(0.0, RecordKind.OPERATION, key, OperationRecord(before=before, after=after))


def _restore(**ops: str) -> Record:
    return Record(0.0, RecordKind.RESTORE, "load", RestoreRecord(values={f"op.{k}": v for k, v in ops.items()}))


def test_a_restarted_controller_announcing_what_it_restored_finished_is_no_second_finish() -> None:
    done = DoneOnce([])
    count_finishes([_op("A", INITIAL, EXECUTING), _op("A", EXECUTING, FINISHED)], done)
    count_finishes([_restore(A="finished"), _op("A", INITIAL, FINISHED)], done)
    assert done.finishes == {"A": 1} and not done.redone()
    assert done.text() == "from 0 recordings: each of 1 finished operations finished once"


def test_a_finish_whose_record_died_with_the_killed_controller_is_known_from_the_restored_state() -> None:
    done = DoneOnce([])
    count_finishes([_op("A", INITIAL, EXECUTING)], done)  # its finish was not handed over before the kill
    count_finishes([_restore(A="finished"), _op("A", INITIAL, FINISHED)], done)
    assert done.finishes == {"A": 1} and done.restored_only == {"A"} and not done.redone()
    assert "finished once (1 known from a restarted controller's restored state: A)" in done.text()


def test_a_controller_that_lost_its_state_and_finishes_again_redid_the_operation() -> None:
    done = DoneOnce([])
    count_finishes([_op("A", INITIAL, EXECUTING), _op("A", EXECUTING, FINISHED)], done)
    count_finishes([_op("A", INITIAL, FINISHED)], done)  # nothing restored
    assert done.redone() == {"A": 2}
    assert done.text().startswith("REDONE") and "A 2 times" in done.text()


def test_an_operation_reset_may_finish_again() -> None:
    done = DoneOnce([])
    count_finishes([_op("A", EXECUTING, FINISHED), _op("A", FINISHED, INITIAL),
                    _op("A", INITIAL, EXECUTING), _op("A", EXECUTING, FINISHED)], done)
    assert done.finishes == {"A": 2} and not done.redone()


# --- the supervisor with small processes -----------------------------------------------------------

def _python(code: str) -> list[str]:
    return [sys.executable, "-c", code]


async def test_a_process_killed_is_restarted_without_its_first_start_arguments(tmp_path: Path) -> None:
    marker = tmp_path / "argv"
    code = f"import sys, time; open({str(marker)!r}, 'a').write(' '.join(sys.argv[1:]) + '\\n'); time.sleep(60)"
    lines: list[str] = []
    supervisor = Supervisor([Child("hub", _python(code), tmp_path / "hub.log", first_start_args=["--fresh"])],
                            FAST_RESTART, lines.append)
    await supervisor.start()
    try:
        async with asyncio.timeout(20):
            while not marker.exists():
                await asyncio.sleep(0.05)
            first = supervisor.pid("hub")
            assert supervisor.kill("hub") == first
            while supervisor.restarts["hub"] == 0 or supervisor.pid("hub") is None \
                    or len(marker.read_text().splitlines()) < 2:
                await asyncio.sleep(0.05)
    finally:
        await supervisor.stop()
    assert marker.read_text().splitlines() == ["--fresh", ""]
    assert supervisor.restart_counts() == "hub 1" and supervisor.gave_up is None
    assert any("EXITED  hub: killed by SIGKILL; restart 1 in 0.1 s" in line for line in lines), lines
    assert any("restarted  hub" in line for line in lines), lines
    assert "--- hubctl up: restart 1" in (tmp_path / "hub.log").read_text()


async def test_a_process_that_keeps_dying_hits_its_start_limit(tmp_path: Path) -> None:
    code = "import sys; print('cannot open /dev/i2c-1', flush=True); sys.exit(3)"
    supervisor = Supervisor([Child("pi-tool", _python(code), tmp_path / "pi-tool.log")], FAST_RESTART, print)
    await supervisor.start()
    try:
        async with asyncio.timeout(30):
            await supervisor.failed.wait()
    finally:
        await supervisor.stop()
    assert supervisor.gave_up is not None and supervisor.restarts["pi-tool"] == 2
    message = supervisor.gave_up.message()
    assert message.startswith("pi-tool keeps dying: it hit its start limit (3 starts within 30 s; "
                              "StartLimitBurst=3, StartLimitIntervalSec=30s)"), message
    assert "it last exited with status 3" in message and "| cannot open /dev/i2c-1" in message


# --- whole runs: the fault station as processes ----------------------------------------------------

@pytest.fixture
def fault_station(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """tests/fault_station's hubs.toml under a name of its own, recording into the test's directory."""
    monkeypatch.chdir(ROOT)
    monkeypatch.setenv("PYTHONPATH", str(ROOT))  # the processes import the station's model from tests/
    config = write_config(tmp_path, prefix="supervise")
    with config.open("a") as handle:
        handle.write(f'\n[controller.recording]\ndir = "{tmp_path / "runs"}"\n')
    yield config


async def _up(config: Path, **options: object) -> tuple[int, str]:
    lines: list[str] = []
    code = await run_station(Options(config=str(config), run_dir=config.parent / "up", time_limit=120.0,
                                     **options), say=lines.append)  # type: ignore[arg-type]  # each test's Options fields
    return code, "\n".join(lines)


def _recordings(config: Path) -> list[Path]:
    station, _ = load_station(config)
    return run_recordings(str(config), station.station.name, 0.0)


def tightened_per_bolt(config: Path) -> dict[str | None, int]:
    """Each rising edge of nr.tqr_m the controllers recorded, by the robot's pose then, over all recordings of
    the run. A new controller's first state of a resource holds only what differs from the model's initial
    values (what it starts from); the edges compare with the values last recorded before, by any controller."""
    _, model = load_station(config)
    initial = {r.name: {v.path: v.initial for v in r.measured} for r in model.resources}
    last: dict[str, object] = {}
    edges: dict[str | None, int] = {}
    for path in _recordings(config):
        seen: set[str] = set()
        with open_run(path) as run:
            for record in run.events(kinds={RecordKind.STATE}):
                assert isinstance(record.data, StateRecord)
                values = record.data.values
                if record.key not in seen:
                    seen.add(record.key)
                    values = {**initial[record.key], **values}
                for variable, value in values.items():
                    if variable == "nr.tqr_m" and value and not last.get(variable):
                        pose = last.get("ur.pos_m")
                        bolt = next((f"bolt{i}" for i, p in BOLT_POSES.items() if p == pose), None)
                        edges[bolt] = edges.get(bolt, 0) + 1
                    last[variable] = value
    return edges


def assert_each_bolt_tightened_once(config: Path, output: str) -> None:
    assert tightened_per_bolt(config) == {f"bolt{i}": 1 for i in BOLTS}, output
    assert "each of 4 finished operations finished once" in output, output


@pytest.mark.slow
@pytest.mark.timeout(180)
async def test_a_hub_killed_mid_run_is_restarted_and_the_run_finishes(fault_station: Path) -> None:
    code, output = await _up(fault_station, chaos_plan=ChaosPlan(0, (Kill("pi-tool", 1, 0.0),)))
    assert code == 0, output
    assert "finished: 4/4 operations" in output
    assert "CHAOS  kill -9 pi-tool" in output and "EXITED  pi-tool: killed by SIGKILL; restart 1 in 1.0 s" in output
    assert "restarted  pi-tool" in output and "restarts: pi-tool 1\n" in output + "\n"
    assert_each_bolt_tightened_once(fault_station, output)


@pytest.mark.slow
@pytest.mark.timeout(180)
async def test_the_controller_killed_mid_run_resumes_from_its_database_and_does_each_operation_once(
        fault_station: Path) -> None:
    code, output = await _up(fault_station, chaos_plan=ChaosPlan(0, (Kill("controller", 1, 0.3),)))
    assert code == 0, output
    assert "finished: 4/4 operations" in output and "restarts: controller 1" in output
    _first, second = _recordings(fault_station)
    with open_run(second) as run:  # the restarted controller took what the first had finished from its SQLite
        restored = [r.data_as(RestoreRecord) for r in run.events(kinds={RecordKind.RESTORE})]
    assert restored and "finished" in {v for r in restored for k, v in r.values.items() if k.startswith("op.")}, \
        restored
    assert_each_bolt_tightened_once(fault_station, output)


@pytest.mark.slow
@pytest.mark.timeout(180)
async def test_chaos_3_with_seed_1_finishes_with_each_operation_done_once(fault_station: Path) -> None:
    code, output = await _up(fault_station, chaos=3, seed=1)
    assert code == 0, output
    assert "finished: 4/4 operations" in output and "chaos (seed 1): 3 of 3 kills done" in output, output
    assert output.count("CHAOS  kill -9") == 3 and output.count("restarted  ") == 3, output
    assert_each_bolt_tightened_once(fault_station, output)


@pytest.mark.slow
@pytest.mark.timeout(180)
async def test_a_hub_that_keeps_dying_ends_the_run_with_its_start_limit(fault_station: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    commands = station_module.child_commands

    def broken_pi_tool(*args: object, **kwargs: object) -> list[Child]:
        children = commands(*args, **kwargs)  # type: ignore[arg-type]  # passed on as run_station gave them
        for child in children:
            if child.name == "pi-tool":
                child.argv = _python("import sys; print('pi-tool: no nutrunner on /dev/i2c-1', flush=True); "
                                     "sys.exit(3)")
        return children

    monkeypatch.setattr(station_module, "child_commands", broken_pi_tool)
    code, output = await _up(fault_station, restart=FAST_RESTART)
    assert code == 1, output
    assert "pi-tool keeps dying: it hit its start limit (3 starts within 30 s" in output, output
    assert "it last exited with status 3" in output and "| pi-tool: no nutrunner on /dev/i2c-1" in output
    assert "restarts: pi-tool 2" in output and "finished: 4/4" not in output, output
