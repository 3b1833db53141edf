"""The controller's one loop (controller/loop.py) and its shells: the live controller service and the
in-process runner decide the same on the same inputs; the in-process runner honours hubs.toml's `delay` and
`hubctl up --in-process --time-limit`; the outbox's seq and the event log's bound and cursors."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from common.bus.memory_bus import MemoryBus, MemoryHub
from common.bus.protocol import Sample
from common.config.hubs_toml import StationConfig, load_station
from common.model import Duration, Model, Value
from common.wire.ctl import (
    EVENT_WINDOW,
    ConsoleEvent,
    HubGone,
    PlanFound,
    ReplanCause,
    Replanned,
    ReplanReason,
    StatusMessage,
)
from common.wire.messages import HubStatus
from controller.events import EventLog
from controller.outbox import CommandVariable, Outbox
from controller.recording.reader import Record
from controller.recording.schema import RecordKind
from controller.service import ControllerService
from deploy.cli import main as hubctl
from deploy.local.inprocess import emulated_delays, run_in_process
from deploy.local.station import Progress
from deploy.replay.replay import compared, is_decision, recorded_answer

ROOT = Path(__file__).resolve().parent.parent
STATION = ROOT / "tests" / "fault_station" / "hubs.toml"
INGESTED = "ingested"  # a step of the capture: measured values the core took


class Capture:
    """A run recording's sink that keeps everything in order: the records and the values ingested."""

    def __init__(self) -> None:
        self.steps: list[tuple[str, Any]] = []  # (record kind or INGESTED, the record or the values)

    def put(self, t: float, kind: RecordKind, key: str, data: Any) -> None:
        self.steps.append((kind.value, Record(t, kind, key, data)))

    def ingested(self, t: float, changed: dict[str, Value], hub_states: Any) -> None:
        if changed:
            self.steps.append((INGESTED, dict(changed)))

    def update_meta(self, **fields: Any) -> None:
        pass

    def close(self) -> None:
        pass

    def decisions(self) -> list[tuple[Any, ...]]:
        return [compared(record) for kind, record in self.steps if kind != INGESTED and is_decision(record)]


def states(config: StationConfig, model: Model, service: ControllerService, measured: dict[str, Value],
           resources: set[str], seq: int) -> list[Sample]:
    """Each resource's state as its hub publishes it, with the measured values `measured` holds."""
    samples = []
    for resource in sorted(resources):
        codec = service.codecs[resource]
        values = {v.name: measured[v.path] for v in codec.measured}
        state = codec.state(values, status=HubStatus.OK, seq=seq, hub=config.resources[resource].name)
        samples.append(Sample(config.keys.state(resource), codec.encode_state(state)))
    return samples


@pytest.mark.parametrize("station", [ROOT / "hubs.toml", ROOT / "examples" / "machine_tending" / "hubs.toml"],
                         ids=["reference", "machine_tending"])
async def test_the_live_controller_and_the_in_process_runner_decide_the_same_on_the_same_inputs(
        station: Path, tmp_path: Path) -> None:
    config, model = load_station(station)
    in_process = Capture()
    summary = run_in_process(model, delays=emulated_delays(config), recording=in_process)
    assert summary.finished and summary.replans
    bus = await MemoryBus(MemoryHub()).open()
    service = ControllerService(config, model, bus, db=str(tmp_path / "controller.sqlite"), planner_process=False)
    live = Capture()
    service.recorder.sink = live
    service.watchdog.clock = lambda: 0.0  # no state goes stale and no mirror lags while the test runs
    try:
        await service.station_hold.acquire()
        service._restore()  # nothing persisted: every operation requested, as at a first start
        for hub in config.hubs:
            service.watchdog.hub_alive(hub, True)
        measured = {v.path: v.initial for r in model.resources for v in r.measured}
        service.ingest.batch(states(config, model, service, measured, set(service.codecs), 0))  # every hub heard
        # The run's inputs, as the live controller takes them: states through its intake, its own ticks (the
        # watchdog's verdicts, held resources, commands published), and the plans found, adopted as its
        # planning client adopts a first answer.
        request = None
        for seq, (kind, step) in enumerate(in_process.steps, start=1):
            if kind == INGESTED:
                measured.update(step)
                touched = {path.split(".", 1)[0] for path in step}
                assert service.ingest.batch(states(config, model, service, measured, touched, seq))
            elif kind == RecordKind.TICK:
                service._tick()
            elif kind == RecordKind.PLAN_REQUEST:
                request = service.loop.plan_request()
                assert request is not None
            elif kind == RecordKind.PLAN:
                assert request is not None and step.data.answer == "first"
                service.loop.adopt(request, recorded_answer(service.compiled, request, step.data))
    finally:
        service.station_hold.release()
        service.store.close()
        await bus.close()
    decided = in_process.decisions()
    assert {d[0] for d in decided} >= {RecordKind.COMMAND, RecordKind.OPERATION, RecordKind.PLAN}
    assert live.decisions() == decided


def _station_time(output: str) -> float:
    found = re.search(r"station time ([0-9.]+) s \(emulated\)", output)
    assert found is not None, output
    return float(found.group(1))


def test_the_in_process_runner_takes_each_devices_delay_from_hubs_toml(tmp_path: Path,
                                                                       capsys: pytest.CaptureFixture[str]) -> None:
    config, _ = load_station(STATION)
    assert emulated_delays(config) == {"nr": Duration.fixed(0.25), "ur": Duration.fixed(0.15)}
    slow = tmp_path / "hubs.toml"
    slow.write_text(STATION.read_text().replace("delay = 0.15", "delay = 1.5"))
    times = []
    for path in (STATION, slow):
        assert hubctl(["up", "--in-process", "--config", str(path), "--no-record"]) == 0
        times.append(_station_time(capsys.readouterr().out))
    as_given, slower = times
    assert slower > as_given + 5.0, times  # every robot move's two effects take 1.35 s longer


def test_the_in_process_runner_stops_at_its_time_limit(capsys: pytest.CaptureFixture[str]) -> None:
    assert hubctl(["up", "--in-process", "--config", str(STATION), "--no-record", "--time-limit", "2"]) == 1
    output = capsys.readouterr().out
    assert "NOT finished" in output and "time limit of 2.0 emulated seconds reached" in output
    assert _station_time(output) <= 2.0 + 1.5  # the first effect due after the limit, at most a move


def test_the_outbox_sends_a_new_seq_for_new_values_the_same_seq_again_and_nothing_to_a_held_resource() -> None:
    outbox = Outbox({"nr": [CommandVariable("run_c", "nr.run_c", 0)],
                     "ur": [CommandVariable("goto_c", "ur.goto_c", 1)]})
    first = outbox.changed((False, "home"), frozenset({"ur"}))
    assert [(c.resource, c.values, c.seq, c.changed) for c in first] == [("nr", {"run_c": False}, 0, True)]
    assert outbox.changed((False, "home"), frozenset({"ur"})) == []
    assert [(c.resource, c.seq, c.changed) for c in outbox.every((True, "home"), frozenset())] == [
        ("nr", 1, True), ("ur", 0, True)]
    assert [(c.resource, c.seq, c.changed) for c in outbox.every((True, "home"), frozenset())] == [
        ("nr", 1, False), ("ur", 0, False)]
    assert outbox.highest_seq("nr") == 1 and outbox.highest_seq("camera") == -1


def test_the_event_log_keeps_its_newest_events_and_a_cursor_reads_what_is_new_and_what_it_missed() -> None:
    log = EventLog(bound=4)
    cursor = log.total
    events = [HubGone(f"hub{i}") for i in range(6)] + [PlanFound("Op", 2)]
    for event in events[:3]:
        log.emit(event)
    read = log.since(cursor)
    assert read.events == events[:3] and read.cursor == 3 and read.missed == 0
    for event in events[3:]:
        log.emit(event)
    assert list(log) == events[3:] == log.recent(10) and log.recent(2) == events[5:] and log.recent(0) == []
    assert log.total == 7 and log.faults == 6  # a hub gone is a fault, a plan found is not
    behind = log.since(read.cursor)  # 4 new, all still held
    assert behind.events == events[3:] and behind.cursor == 7 and behind.missed == 0
    far_behind = log.since(0)  # 7 new, the bound kept 4
    assert far_behind.events == events[3:] and far_behind.missed == 3
    assert log.since(far_behind.cursor).events == [] and log.since(far_behind.cursor).cursor == 7
    log.emit(Replanned(ReplanCause(ReplanReason.GOALS_CHANGED)))
    assert [type(e) for e in log.since(7).events] == [Replanned]
    with pytest.raises(ValueError):
        EventLog(bound=0)



def test_hubctl_up_counts_the_faults_of_the_whole_run_not_of_the_last_statuss_window() -> None:
    progress = Progress(lambda _line: None, 0)
    logged: list[ConsoleEvent] = []

    def status(controller: str) -> StatusMessage:
        return StatusMessage(station="s", controller=controller, time=0.0, uptime=0.0,
                             events=logged[-EVENT_WINDOW:], events_total=len(logged))

    for i in range(30):  # 30 faults, fewer than a window at a time between two statuses
        logged += [HubGone(f"hub{i}"), PlanFound("Op", 1)]
        progress.update(status("c-1"))
    progress.update(status("c-1"))  # nothing new
    assert progress.faults == 30 and progress.last_fault == HubGone("hub29")
    logged.clear()
    logged.append(HubGone("again"))
    progress.update(status("c-2"))  # a restarted controller: its log starts afresh
    assert progress.faults == 31 and progress.last_fault == HubGone("again")
