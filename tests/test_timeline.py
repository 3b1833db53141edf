"""`hubctl timeline` and `hubctl runs`: a recorded run drawn as a Gantt chart, the recorded runs listed.

The screenshot test records an in-process run of the reference station, computes its timeline,
checks the spans and markers against the recording's own records, renders it to PNG and reads the
picture back: its size, and ink in each lane's band where that lane has a span. A hand-written
recording of the fault station checks the unhealthy period (shaded) and the fault (marked).
"""

from __future__ import annotations

import asyncio
import itertools
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread
from textual.widgets import Static

from common.model import OperationState
from common.stations import load_model
from common.wire.ctl import HubGone
from controller.console.app import ConsoleApp
from controller.console.gantt import NAME_WIDTH, gantt_lines
from controller.console.station import StationInfo
from controller.planner.policy import VIRTUAL_BUDGET
from controller.recording.reader import Run, open_run
from controller.recording.schema import (
    CommandRecord,
    OperationRecord,
    PlanRequestRecord,
    RecordKind,
    RunMeta,
    RunMode,
    StateRecord,
    WatchdogRecord,
    WatchdogVerdict,
)
from controller.recording.writer import RECORDING_DIR_ENV, RecordingWriter
from controller.timeline.model import Timeline, build_timeline
from controller.timeline.render import DPI, WIDTH_IN, Drawn, render
from deploy.cli import main as hubctl
from deploy.local.inprocess import RunSummary, run_in_process
from deploy.local.recordings import in_process_recording

REFERENCE_MODEL = "common.stations.engine_assembly:build_model"
FAULT_MODEL = "tests.fault_station.model:build_model"


@pytest.fixture(scope="module")
def reference_run() -> Iterator[tuple[RunSummary, Path]]:
    model = load_model(REFERENCE_MODEL)
    recording = in_process_recording(model, REFERENCE_MODEL, None, seed=1, budget=VIRTUAL_BUDGET)
    assert recording is not None, "the run's recording could not be opened"
    summary = run_in_process(model, seed=1, budget=VIRTUAL_BUDGET, recording=recording)
    assert summary.finished, summary.reason
    yield summary, recording.path


def records(run: Run, kind: RecordKind) -> list[tuple[float, str, object]]:
    return [(r.t, r.key, r.data) for r in run.events(kinds=[kind])]


def test_the_spans_and_markers_are_the_recordings_events(reference_run: tuple[RunSummary, Path]) -> None:
    summary, path = reference_run
    with open_run(path) as run:
        timeline = build_timeline(run)
        operations = records(run, RecordKind.OPERATION)
        commands = {(t, key) for t, key, _ in records(run, RecordKind.COMMAND)}
        states = {(t, key) for t, key, _ in records(run, RecordKind.STATE)}
        requests = records(run, RecordKind.PLAN_REQUEST)
    model = load_model(REFERENCE_MODEL)
    assert timeline.resources == [r.name for r in model.resources]
    assert timeline.operations == [op.name for op in model.operations]
    # An operation's lane: a span per state it entered, from that record to the next one of it.
    entered = sorted((key, t, data.after) for t, key, data in operations)  # type: ignore[attr-defined]  # operation records
    assert sorted((s.lane, s.start, s.label) for s in timeline.operation_spans) == entered
    # Every ability the controller started is a span, begun by a command and ended by a measured state.
    assert len(timeline.abilities) == summary.abilities > 50
    for span in timeline.abilities:
        assert span.outcome == "done" and span.start < span.end, span
        assert (span.start, span.lane) in commands, span
        assert (span.end, span.lane) in states, span
    assert [(m.t, m.kind) for m in timeline.plans] == [(t, "plan" if i == 0 else "replan")
                                                       for i, (t, _, _) in enumerate(requests)]
    assert all(m.text.startswith(data.reason) and "steps" in m.text  # type: ignore[attr-defined]  # plan requests
               for m, (_, _, data) in zip(timeline.plans, requests, strict=True))
    assert not timeline.faults and not timeline.unhealthy and not timeline.note


def ink(picture: np.ndarray, drawn: Drawn, lane: str, start: float, end: float) -> float:
    """The share of pixels that are not white in the lane's band between times start and end."""
    top, bottom = drawn.bands[lane]
    rows = slice(int(top) + 2, int(bottom) - 1)
    columns = slice(int(drawn.column(start)) + 1, max(int(drawn.column(end)) - 1, int(drawn.column(start)) + 2))
    region = picture[rows, columns, :3]
    return float((region.min(axis=2) < 0.9).mean())


def test_the_png_has_a_band_per_lane_with_ink_where_its_spans_are(reference_run: tuple[RunSummary, Path],
                                                                   tmp_path: Path) -> None:
    _, path = reference_run
    with open_run(path) as run:
        timeline = build_timeline(run)
    drawn = render(timeline, tmp_path / "timeline.png")
    picture = imread(tmp_path / "timeline.png")
    assert picture.shape[:2] == (drawn.height, drawn.width) and drawn.width == int(WIDTH_IN * DPI)
    bands = [drawn.bands[lane] for lane in timeline.lanes]
    assert all(a[1] < b[0] for a, b in itertools.pairwise(bands))  # top to bottom, apart
    for lane in timeline.lanes:
        spans = [s for s in timeline.abilities + timeline.operation_spans if s.lane == lane]
        if spans:
            longest = max(spans, key=lambda s: s.end - s.start)
            assert ink(picture, drawn, lane, longest.start, longest.end) > 0.9, lane
    blank = [lane for lane in timeline.resources if not any(s.lane == lane for s in timeline.abilities)]
    assert blank == ["rfid", "cam", "dock"]  # no ability with a starting phase ran on them: nothing drawn
    first_plan_line, second = timeline.plans[0].t, timeline.plans[1].t
    for lane in blank:
        assert ink(picture, drawn, lane, first_plan_line + 0.1, second - 0.1) == 0.0, lane


def fault_recording(directory: Path) -> Path:
    """The fault station: nr unhealthy from t=2 to t=5 (its hub gone at 1.9), ur moving meanwhile."""
    writer = RecordingWriter(directory, RunMeta(station="fault_station", model=FAULT_MODEL, mode=RunMode.SERVICE,
                                                requested=["TightenBolt1"], started=1000.0),
                             max_bytes=1 << 20, keep=10, flush_s=0.01)
    put = writer.put
    put(0.0, RecordKind.OPERATION, "TightenBolt1",
        OperationRecord(before=OperationState.INITIAL, after=OperationState.EXECUTING))
    put(0.0, RecordKind.PLAN_REQUEST, "1", PlanRequestRecord(generation=1, goals=["TightenBolt1"], reason="start"))
    put(1.0, RecordKind.COMMAND, "ur", CommandRecord(values={"ur.ref_pos_c": "at_bolt1"}, seq=1))
    put(1.5, RecordKind.STATE, "ur", StateRecord(values={"ur.pos_m": "unknown"}))
    put(1.9, RecordKind.EVENT, "hub_gone", HubGone("pi-tool"))
    put(2.0, RecordKind.WATCHDOG, "nr",
        WatchdogRecord(verdict=WatchdogVerdict.UNHEALTHY, detail="hub pi-tool not alive"))
    put(2.0, RecordKind.PLAN_REQUEST, "2", PlanRequestRecord(generation=2, goals=["TightenBolt1"],
                                                             reason="resource health changed", detail="nr"))
    put(3.0, RecordKind.STATE, "ur", StateRecord(values={"ur.pos_m": "at_bolt1"}))
    put(5.0, RecordKind.WATCHDOG, "nr", WatchdogRecord(verdict=WatchdogVerdict.RECOVERED))
    put(6.0, RecordKind.OPERATION, "TightenBolt1",
        OperationRecord(before=OperationState.EXECUTING, after=OperationState.ERROR))
    writer.update_meta(outcome="stopped", duration=6.0)
    writer.close()
    return writer.path


def test_an_unhealthy_period_is_shaded_and_a_fault_marked(tmp_path: Path) -> None:
    with open_run(fault_recording(tmp_path)) as run:
        timeline: Timeline = build_timeline(run)
    (period,) = timeline.unhealthy
    assert (period.lane, period.start, period.end, period.reason) == ("nr", 2.0, 5.0, "hub pi-tool not alive")
    (fault,) = timeline.faults
    assert (fault.t, fault.text) == (1.9, "hub pi-tool gone")
    (move,) = timeline.abilities
    assert (move.lane, move.label, move.start, move.end, move.outcome) == ("ur", "move_to_at_bolt1", 1.0, 3.0, "done")
    assert [(s.label, s.start, s.end) for s in timeline.operation_spans] == [("executing", 0.0, 6.0),
                                                                              ("error", 6.0, 6.0)]
    assert [m.text for m in timeline.plans] == ["start", "resource health changed: nr"]

    drawn = render(timeline, tmp_path / "fault.png")
    picture = imread(tmp_path / "fault.png")
    top, bottom = drawn.bands["nr"]
    rows = slice(int(top) + 2, int(bottom) - 1)

    def reddish(start: float, end: float) -> float:
        region = picture[rows, int(drawn.column(start)) + 2:int(drawn.column(end)) - 2, :3]
        return float(((region[..., 0] > region[..., 2] + 0.1) & (region.min(axis=2) < 0.95)).mean())

    assert reddish(2.1, 2.9) > 0.5 and reddish(3.1, 4.9) > 0.5  # shaded while unhealthy
    assert reddish(5.2, 5.8) == 0.0 and reddish(0.2, 0.8) == 0.0


def test_hubctl_timeline_writes_one_self_contained_html_file_or_svg_and_refuses_other_formats(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    recording = fault_recording(tmp_path)
    assert hubctl(["timeline", str(recording)]) == 0
    page = recording.with_suffix(".html").read_text()
    assert page.count("<svg") == 1 and "src=" not in page and "http://www.w3.org/2000/svg" in page
    assert "resource health changed: nr" in page and "hub pi-tool gone" in page and "2.0-5.0 s" in page
    assert hubctl(["timeline", str(recording), "--out", str(tmp_path / "t.svg")]) == 0
    assert (tmp_path / "t.svg").read_text().lstrip().startswith("<?xml")
    out = capsys.readouterr().out
    assert "1 unhealthy periods, 1 faults" in out and "2  t=2.0 s  replan: resource health changed: nr" in out
    assert hubctl(["timeline", str(recording), "--out", str(tmp_path / "t.txt")]) == 2
    assert "not .txt" in capsys.readouterr().err


def test_hubctl_runs_lists_the_runs_newest_first_with_their_outcome(tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    outcomes = [("finished", 45, 45, 3, 0, 51.2), ("stopped", 12, 45, 9, 2, 20.0), ("running", 4, 45, 1, 1, 0.0)]
    for i, (outcome, done, total, replans, faults, duration) in enumerate(outcomes):
        writer = RecordingWriter(tmp_path, RunMeta(station="s", mode=RunMode.UP, started=1_700_000_000.0 + 60 * i,
                                                   run=f"run{i}"), max_bytes=1 << 20, keep=10)
        if outcome != "running":  # a killed controller never writes its end
            writer.update_meta(outcome=outcome, operations_done=done, operations_total=total, plans=replans + 1,
                               replans=replans, faults=faults, duration=duration)
        writer.close()
    (tmp_path / "broken.sqlite").write_bytes(b"not a database")
    assert hubctl(["runs", str(tmp_path)]) == 0
    header, *rows = capsys.readouterr().out.splitlines()
    assert header.split()[:5] == ["started", "run", "mode", "outcome", "operations"]
    assert [row.split()[2] for row in rows[:3]] == ["run2", "run1", "run0"]  # newest first
    assert rows[0].split()[3:9] == ["up", "running/killed", "0/0", "0", "0", "0"]
    assert rows[1].split()[3:10] == ["up", "stopped", "12/45", "10", "9", "2", "20.0"]
    assert rows[2].split()[3:10] == ["up", "finished", "45/45", "4", "3", "0", "51.2"]
    assert "unreadable" in rows[3] and "broken.sqlite" in rows[3]
    assert hubctl(["runs", str(tmp_path / "none")]) == 0
    assert "no recorded run in" in capsys.readouterr().out


def test_the_console_gantt_has_the_same_spans_in_text(tmp_path: Path) -> None:
    with open_run(fault_recording(tmp_path)) as run:
        timeline = build_timeline(run)
    lines = {line.plain[:NAME_WIDTH].strip(): line.plain[NAME_WIDTH + 1:] for line in gantt_lines(timeline, 79)}
    cells = 79 - NAME_WIDTH - 1  # 60: a tenth of a second each
    assert len(lines["nr"]) == len(lines["ur"]) == len(lines["TightenBolt1"]) == cells
    assert lines["ur"] == " " * 10 + "█" * 20 + " " * 30  # the move, 1.0 to 3.0 s
    assert lines["nr"] == " " * 20 + "░" * 30 + " " * 10  # unhealthy 2.0 to 5.0 s
    assert lines["TightenBolt1"] == "█" * 59 + "█"  # executing, then in error at the end
    assert lines["plans, 6 s"] == "|" + " " * 19 + "▼" + " " * 39


class Quiet:
    """A feed from no controller: the timeline panel reads the recording, not the bus."""

    status = plan = snapshot = None
    selftests: dict[str, object] = {}
    version = 0
    connected = False

    async def run(self) -> None:
        await asyncio.get_running_loop().create_future()

    async def request(self, request: object) -> object:
        raise AssertionError("no request is made")


async def test_the_console_shows_the_current_runs_timeline_on_t(tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(RECORDING_DIR_ENV, str(tmp_path))
    fault_recording(tmp_path)
    model = load_model(FAULT_MODEL)
    info = StationInfo(station="fault_station", kinds={p: v.kind for p, v in model.variables.items()})
    app = ConsoleApp(info, Quiet())  # type: ignore[arg-type]  # a canned feed
    async with app.run_test(size=(120, 40)) as pilot:
        await pilot.press("t")
        for _ in range(200):
            await pilot.pause(0.05)
            if app.timeline is not None:
                break
        await pilot.pause(0.1)
        shown = str(app.query_one("#timeline", Static).render())
        assert app.query_one("#panels").has_class("hidden")
        assert "░" in shown and "TightenBolt1" in shown and "resource health changed: nr" in shown, shown
        await pilot.press("t")
        assert not app.query_one("#panels").has_class("hidden")
