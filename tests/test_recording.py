"""Run recordings (common/recording): written by a process of their own, bounded, read back in order."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from common.config.hubs_toml import ConfigError, RecordingConfig, parse_config
from common.model import OperationState
from common.stations import load_model
from common.wire.ctl import HubGone
from common.wire.messages import HubStatus
from controller.recording.hooks import RunRecorder, open_recording
from controller.recording.reader import RecordingError, list_runs, open_run
from controller.recording.schema import (
    OperationRecord,
    PlanAnswer,
    PlanRecord,
    RecordKind,
    RunMeta,
    RunMode,
    RunOutcome,
    StateRecord,
    TickRecord,
    WatchdogRecord,
    WatchdogVerdict,
)
from controller.recording.writer import RECORDING_DIR_ENV, RecordingWriter
from controller.stack import build_controller_stack

MB = 1024 * 1024
FAULT_MODEL = "tests.fault_station.model:build_model"


def writer(directory: Path, **options: object) -> RecordingWriter:
    settings: dict[str, object] = {"max_bytes": 50 * MB, "keep": 10, "flush_s": 0.01} | options
    return RecordingWriter(directory, RunMeta(station="s", mode=RunMode.IN_PROCESS, started=1000.0), **settings)  # type: ignore[arg-type]  # each test passes its keywords


def test_the_vocabularies_of_a_recording_read_back_as_their_enums_in_the_words_recorded_before(
        tmp_path: Path) -> None:
    # The words on disk are those the recordings made before the enums hold (tests/replays too).
    w = writer(tmp_path)
    w.put(0.5, RecordKind.WATCHDOG, "nr", WatchdogRecord(verdict=WatchdogVerdict.UNHEALTHY, detail="stale"))
    w.put(0.6, RecordKind.PLAN, "1", PlanRecord(generation=1, answer=PlanAnswer.IMPROVEMENT, taken=True, goals=[]))
    w.put(0.7, RecordKind.OPERATION, "Tighten",
          OperationRecord(before=OperationState.EXECUTING, after=OperationState.FINISHED))
    w.update_meta(outcome=RunOutcome.STUCK)
    w.close()

    with open_run(w.path) as run:
        assert run.meta.mode is RunMode.IN_PROCESS and run.meta.outcome is RunOutcome.STUCK
        stored = dict(run._connections[0].execute("SELECT key, value FROM run_meta"))
        assert (stored["mode"], stored["outcome"]) == ('"in-process"', '"stuck"')
        verdict, plan, operation = (r.data for r in run.events())
        assert isinstance(verdict, WatchdogRecord) and verdict.verdict is WatchdogVerdict.UNHEALTHY
        assert isinstance(plan, PlanRecord) and plan.answer is PlanAnswer.IMPROVEMENT
        assert isinstance(operation, OperationRecord) and operation.after is OperationState.FINISHED
        data = [row[0] for row in run._connections[0].execute("SELECT data FROM events ORDER BY id")]
        assert b"\xa9unhealthy" in data[0] and b"\xabimprovement" in data[1] and b"\xa8finished" in data[2]


def test_records_are_read_back_in_order_with_their_types_and_filters(tmp_path: Path) -> None:
    w = writer(tmp_path)
    w.put(0.5, RecordKind.STATE, "nr", StateRecord(values={"nr.run_m": True}, status=HubStatus.OK, mirror_seq=3))
    w.put(0.5, RecordKind.TICK, "", TickRecord())
    w.put(1.0, RecordKind.EVENT, "hub_gone", HubGone("pi-tool"))
    w.put(2.0, RecordKind.OPERATION, "Tighten",
          OperationRecord(before=OperationState.INITIAL, after=OperationState.EXECUTING))
    w.update_meta(outcome="finished", operations_done=1)
    w.close()

    with open_run(w.path) as run:
        assert run.meta.station == "s" and run.meta.outcome == "finished" and run.meta.operations_done == 1
        assert [(r.t, r.kind, r.key) for r in run.events()] == [
            (0.5, RecordKind.STATE, "nr"), (0.5, RecordKind.TICK, ""), (1.0, RecordKind.EVENT, "hub_gone"),
            (2.0, RecordKind.OPERATION, "Tighten")]
        (state,) = run.events(kinds=["state"])
        assert state.data == StateRecord(values={"nr.run_m": True}, status=HubStatus.OK, mirror_seq=3)
        assert [r.data for r in run.events(kinds={RecordKind.EVENT}, since=0.9, until=1.1)] == [HubGone("pi-tool")]
        assert [r.kind for r in run.events(since=0.6, key="Tighten")] == [RecordKind.OPERATION]
        assert run.end_t == 2.0


def test_a_run_beyond_max_bytes_goes_on_in_part_files_read_as_one_run(tmp_path: Path) -> None:
    w = writer(tmp_path, max_bytes=64 * 1024, flush_s=60.0)
    for batch in range(6):  # each batch is one transaction; the size is checked after each
        for i in range(400):
            w.put(batch * 400 + i, RecordKind.STATE, f"r{i % 7}", StateRecord(values={"r.x": "x" * 40}))
        w.flush()  # one message to the writer process, one transaction (flush_s would wait a minute)
    w.close()

    parts = sorted(tmp_path.glob("*.sqlite"))
    assert len(parts) > 2
    assert all(p.stat().st_size < 2 * 64 * 1024 for p in parts)
    (info,) = list_runs(tmp_path)
    assert info.parts == len(parts) and info.path == w.path
    with open_run(parts[-1]) as run:  # any part opens the whole run
        assert [r.t for r in run.events()] == list(range(2400))


def test_the_directory_keeps_at_most_keep_files_deleting_the_oldest(tmp_path: Path) -> None:
    paths = []
    for started in range(5):
        w = RecordingWriter(tmp_path, RunMeta(station="s", started=1000.0 + started), max_bytes=MB, keep=3)
        w.put(0.0, RecordKind.TICK, "", TickRecord())
        w.close()
        paths.append(w.path)
    assert sorted(tmp_path.glob("*.sqlite")) == sorted(paths[-3:])
    assert [info.path for info in list_runs(tmp_path)] == paths[-3:]


def test_a_stuck_disk_never_blocks_put_and_what_overflows_is_counted(tmp_path: Path) -> None:
    w = writer(tmp_path, backlog_bytes=64 * 1024, flush_s=60.0)
    big = StateRecord(values={"r.x": "x" * 1000})
    os.kill(w._process.pid, signal.SIGSTOP)  # the writer process stuck, as on a disk that does not answer
    try:  # every put returns (a blocked one would hang the test): the pipe fills, then the backlog, then drops
        for i in range(3000):
            w.put(float(i), RecordKind.STATE, "r", big)
            if i % 10 == 9:
                w.flush()
        assert w.dropped > 1000 and w._waiting <= 64 * 1024 + 10 * 1100
    finally:
        os.kill(w._process.pid, signal.SIGCONT)
    w.close()
    with open_run(w.path) as run:  # nothing lost but what was counted
        assert run.meta.dropped == w.dropped
        assert sum(1 for _ in run.events()) == 3000 - w.dropped


def test_a_writer_process_that_ends_early_drops_and_counts_the_rest_and_the_caller_goes_on(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    w = writer(tmp_path)
    w.put(0.0, RecordKind.TICK, "", TickRecord())
    w._process.kill()  # as if the disk were gone: the process stops
    w._process.wait()
    for i in range(100):
        w.put(float(i), RecordKind.TICK, "", TickRecord())
        w.flush()
    w.close()
    assert w.dropped >= 100 and "its writer process ended" in caplog.text


def test_a_record_that_cannot_be_encoded_is_dropped_and_counted_and_the_rest_written(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    w = writer(tmp_path)
    w.put(0.0, RecordKind.TICK, "", TickRecord())
    w.put(0.5, RecordKind.STATE, "nr", StateRecord(values={"nr.run_m": object()}))  # type: ignore[dict-item]  # an unencodable value on purpose
    w.put(1.0, RecordKind.TICK, "", TickRecord())
    w.close()
    assert w.dropped == 1 and "a state record of 'nr' cannot be encoded" in caplog.text
    with open_run(w.path) as run:
        assert [r.t for r in run.events()] == [0.0, 1.0] and run.meta.dropped == 1


KILLED_CONTROLLER = """
import os, signal, sys
from controller.recording.schema import RecordKind, RunMeta, TickRecord
from controller.recording.writer import RecordingWriter
w = RecordingWriter(sys.argv[1], RunMeta(station="s", mode="service", started=1000.0), max_bytes=1 << 20, keep=3)
for i in range(500):
    w.put(float(i), RecordKind.TICK, "", TickRecord())
w.update_meta(requested=["Tighten"])
w.flush()
print(w.path, w._process.pid, flush=True)
os.kill(os.getpid(), signal.SIGKILL)
"""


def _running(pid: int) -> bool:
    """Not ours to wait for (the killed process's child): gone, or a zombie nobody reaped yet."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, ProcessLookupError):
        return False


def test_a_controller_killed_with_kill_9_leaves_a_readable_recording_of_what_it_handed_over(tmp_path: Path) -> None:
    killed = subprocess.run([sys.executable, "-c", KILLED_CONTROLLER, str(tmp_path)], capture_output=True, text=True,
                            timeout=60)
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    name, pid = killed.stdout.split()
    path = Path(name)
    deadline = time.monotonic() + 30
    while _running(int(pid)) and time.monotonic() < deadline:  # its writer process reads to the pipe's end,
        time.sleep(0.05)                                          # writes, exits
    assert not path.with_name(path.name + "-wal").exists()  # completed: one self-contained file
    with open_run(path) as run:
        assert run.meta.outcome is RunOutcome.RUNNING and run.meta.requested == ["Tighten"]  # never closed
        assert [r.t for r in run.events()] == [float(i) for i in range(500)]


def test_an_ingested_batch_is_one_row_read_back_as_one_state_record_per_resource(tmp_path: Path) -> None:
    core = build_controller_stack(load_model(FAULT_MODEL)).control_core(lambda: 0.5)
    w = writer(tmp_path)
    recorder = RunRecorder(core, lambda: 0.5, w)
    recorder.ingested(core.ingest({"nr.run_m": True, "ur.pos_m": "at_bolt1", "nr.tqr_m": True}),
                      [("nr", HubStatus.OK, "", 3), ("ur", HubStatus.OK, "", None)])
    recorder.ingested(core.ingest({"nr.run_m": True}), [("nr", HubStatus.OK, "", 3)])  # nothing changed: no row
    recorder.ingested(core.ingest({"nr.run_m": False}),
                      [("nr", HubStatus.OK, "", 3), ("ur", HubStatus.DEVICE_LOST, "cable", None)])
    w.close()

    with open_run(w.path) as run:
        assert run.meta.format == 2
        assert run._connections[0].execute("SELECT COUNT(*) FROM events").fetchone()[0] == 2
        assert [(r.key, r.data) for r in run.events()] == [
            ("nr", StateRecord(values={"nr.run_m": True, "nr.tqr_m": True}, status=HubStatus.OK, mirror_seq=3)),
            ("ur", StateRecord(values={"ur.pos_m": "at_bolt1"}, status=HubStatus.OK)),
            ("nr", StateRecord(values={"nr.run_m": False}, status=HubStatus.OK, mirror_seq=3)),
            ("ur", StateRecord(status=HubStatus.DEVICE_LOST, detail="cable"))]
        statuses = [r.data_as(StateRecord).status for r in run.events(kinds=["state"], key="ur")]
        assert statuses == [HubStatus.OK, HubStatus.DEVICE_LOST]
        assert [r.kind for r in run.events(kinds=["tick"], key="ur")] == []


def test_a_format_1_recording_is_read_and_an_unknown_format_refused_naming_it(tmp_path: Path) -> None:
    old = RecordingWriter(tmp_path / "old", RunMeta(format=1, started=1000.0), max_bytes=MB, keep=3)
    old.put(0.5, RecordKind.STATE, "nr", StateRecord(values={"nr.run_m": True}))
    old.close()
    with open_run(old.path) as run:
        assert [(r.kind, r.key) for r in run.events(key="nr")] == [(RecordKind.STATE, "nr")]
    new = RecordingWriter(tmp_path / "new", RunMeta(format=3, started=1000.0), max_bytes=MB, keep=3)
    new.close()
    with pytest.raises(RecordingError, match=r"new/.*\.sqlite: recording format 3, this statehub reads formats 1, 2"):
        open_run(new.path)


def test_what_is_not_a_recording_is_refused_with_its_path(tmp_path: Path) -> None:
    bad = tmp_path / "notes.sqlite"
    bad.write_text("not sqlite")
    with pytest.raises(RecordingError, match=r"notes\.sqlite"):
        open_run(bad)
    (info,) = list_runs(tmp_path)
    assert info.problem and info.path == bad


CONFIG = """[station]
name = "s"
model = "m:build"
[controller]
host = "x"
{recording}
[hubs.h]
host = "h"
"""


def test_recording_settings_in_hubs_toml_with_defaults_and_errors_by_key_and_line() -> None:
    default = parse_config(CONFIG.format(recording="")).controller.recording
    assert (default.dir, default.max_mb, default.keep) == ("var/runs", 200.0, 50)
    chosen = parse_config(CONFIG.format(recording='[controller.recording]\ndir = "runs"\nmax_mb = 5\nkeep = 3'))
    assert chosen.controller.recording.max_mb == 5 and chosen.controller.recording.keep == 3
    with pytest.raises(ConfigError) as error:
        parse_config(CONFIG.format(recording="[controller.recording]\nmax_mb = 0\nkeep = 0.5\nsize = 1"))
    assert [(p.line, p.key) for p in error.value.problems] == [
        (7, "controller.recording.max_mb"), (8, "controller.recording.keep"), (9, "controller.recording.size")]


def test_a_recording_that_cannot_be_written_leaves_the_run_unrecorded_and_says_why(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "file").write_text("")  # the configured dir is a file
    monkeypatch.delenv(RECORDING_DIR_ENV)  # the suite's own
    assert open_recording(RecordingConfig(dir=str(tmp_path / "file")), RunMeta(), load_model(FAULT_MODEL)) is None
    assert "the run is not recorded: cannot write into" in caplog.text and "[controller.recording] dir" in caplog.text
