"""The operator console, headless under Textual's pilot, against a running station over Zenoh.

The controller and the hubs are real processes on loopback (tests/fault_station/harness.py),
the controller started with `--hold` so that nothing runs until the console starts it, and
the emulated operator never confirms by itself: the console is the smartwatch. Each test
presses the console's keys and checks both what the console shows and what the
controller publishes (its status and state snapshot, recorded by the harness's watcher).

* `test_console_drives_every_action` (tests/console_station: an operator places two bolts, the
  robot tightens them): pause and resume, start, a refused start with its reason shown,
  stop, start again, confirm, reset, force and unforce a variable (the controller's state
  shows it forced, then not), a refused force; an SVG screenshot mid-run.
* `test_reference_station_runs_to_completion_from_the_console` (the reference station of
  hubs.toml, 45 operations, 8 operator tasks, emulated at 5x speed): start everything with
  one key, confirm each instruction as it appears, watch the station finish.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TypeVar

import msgspec
import pytest
from textual.pilot import Pilot
from textual.widgets import Static

from common.model import OperationState
from common.wire.ctl import ConsoleReply, RequestAnswered
from controller.console.app import ConsoleApp
from controller.console.link import ConsoleLink
from controller.console.station import StationInfo
from tests.fault_station.harness import ROOT, Station, write_config

pytestmark = [pytest.mark.slow, pytest.mark.timeout(360)]

CONSOLE_STATION = ROOT / "tests" / "console_station" / "hubs.toml"
REFERENCE_STATION = ROOT / "hubs.toml"
SCREEN = (200, 60)
T = TypeVar("T")


@pytest.fixture
def console_station(tmp_path: Path) -> Iterator[Station]:
    with Station(tmp_path, config=write_config(tmp_path, CONSOLE_STATION, prefix="console"), hold=True) as station:
        station.start()
        yield station


def console_for(station: Station) -> ConsoleApp:
    info = StationInfo.from_station(station.config, station.model)
    link = ConsoleLink(info.station, [f"tcp/127.0.0.1:{station.port}"], listen=["tcp/127.0.0.1:0"],
                       lease_ms=info.lease_ms)
    return ConsoleApp(info, link)


async def until(pilot: Pilot[None], station: Station, predicate: Callable[[], T], what: str,
                timeout: float = 30.0) -> T:
    """Let the console run until `predicate` returns something truthy (returned); fail with what the station did."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        dead = station.dead()
        if dead:
            raise AssertionError(f"waiting for {what}: {', '.join(dead)} exited; {station.describe()}")
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout} s; {station.describe()}")
        await pilot.pause(0.05)


async def press(pilot: Pilot[None], app: ConsoleApp, station: Station, *keys: str) -> ConsoleReply:
    """Press `keys` and wait for the controller's answer to the request they make."""
    before = len(app.replies)
    await pilot.press(*keys)
    await until(pilot, station, lambda: len(app.replies) > before, f"an answer to {keys}")
    return app.replies[-1][1]


async def on_operation(pilot: Pilot[None], app: ConsoleApp, station: Station, name: str, key: str) -> ConsoleReply:
    app.table("operations").select(name)
    return await press(pilot, app, station, key)


def op_state(station: Station, name: str) -> str | None:
    status = station.watch.status()
    return next((op.state for op in status.operations if op.name == name), None) if status else None


def shown_op_state(app: ConsoleApp, name: str) -> str:
    row = app.table("operations").shown.get(name)
    return str(row[1]) if row else ""


def snapshot_since(station: Station, at: float) -> tuple[dict[str, object], list[str]] | None:
    """The controller's newest state snapshot received after `at` (monotonic): values and forced paths."""
    fresh = [s for s in station.watch.snapshots() if s.at > at]
    return (dict(fresh[-1].message.values), list(fresh[-1].message.forced)) if fresh else None


async def test_console_drives_every_action(console_station: Station, tmp_path: Path) -> None:
    station = console_station
    app = console_for(station)
    async with app.run_test(size=SCREEN) as pilot:
        await until(pilot, station, lambda: len(app.table("operations").shown) == 3, "the console shows the operations")
        await until(pilot, station, lambda: len(app.table("resources").shown) == 3, "the console shows the resources")
        assert op_state(station, "PlaceBolts") == OperationState.INITIAL  # --hold: nothing started by itself

        # Pause, then start: accepted, but it waits for resume.
        assert (await press(pilot, app, station, "p")).accepted
        await until(pilot, station, lambda: station.watch.current_status().paused, "the controller reports paused")
        started = await on_operation(pilot, app, station, "PlaceBolts", "s")
        assert started.accepted and "starts on resume" in started.reason
        assert op_state(station, "PlaceBolts") == OperationState.INITIAL
        assert (await press(pilot, app, station, "p")).accepted  # resume
        await until(pilot, station, lambda: op_state(station, "PlaceBolts") == OperationState.EXECUTING,
                    "PlaceBolts executes")
        await until(pilot, station, lambda: app.state_view.values.get("human.instr_c") == "place_bolts",
                    "the console shows the operator's instruction")
        assert not station.watch.current_status().paused

        # A refused request: its reason is on the screen.
        refused = await on_operation(pilot, app, station, "PlaceBolts", "s")
        assert not refused.accepted and refused.reason == "PlaceBolts is already executing"
        assert "REFUSED: PlaceBolts is already executing" in str(app.query_one("#statusline", Static).content)

        # Stop: back to initial and its plan dropped. The instruction already given stays (an ability
        # under way runs to its end: the operator's ends with a confirmation); start again.
        assert (await on_operation(pilot, app, station, "PlaceBolts", "x")).accepted
        await until(pilot, station, lambda: op_state(station, "PlaceBolts") == OperationState.INITIAL,
                    "PlaceBolts stops")
        await until(pilot, station, lambda: (plan := station.watch.current_status().plan) is None or not plan.goals,
                    "the plan is dropped")
        assert (await on_operation(pilot, app, station, "PlaceBolts", "s")).accepted
        await until(pilot, station, lambda: op_state(station, "PlaceBolts") == OperationState.EXECUTING,
                    "PlaceBolts runs again")

        # The operator confirms on the console: the bolts are placed, the operation finishes.
        confirmed = await press(pilot, app, station, "c")
        assert confirmed.accepted and confirmed.reason == "human confirmed place_bolts"
        await until(pilot, station, lambda: op_state(station, "PlaceBolts") == OperationState.FINISHED,
                    "PlaceBolts finishes")
        await until(pilot, station, lambda: shown_op_state(app, "PlaceBolts") == OperationState.FINISHED,
                    "the console shows PlaceBolts finished")
        await until(pilot, station, lambda: station.watch.snapshot().get("engine.bolt1_e") == "placed",
                    "the controller records the bolts placed")
        refused = await press(pilot, app, station, "c")
        assert not refused.accepted and refused.reason == "human has no instruction to confirm"

        # Reset: the finished operation back to initial (its precondition no longer holds: it stays there).
        assert (await on_operation(pilot, app, station, "PlaceBolts", "r")).accepted
        await until(pilot, station, lambda: op_state(station, "PlaceBolts") == OperationState.INITIAL,
                    "PlaceBolts resets")

        # Force an estimate through the input, see it forced in the controller's state, then undo it.
        forced_at = time.monotonic()
        await pilot.press("f")
        app.query_one("#force").value = ""  # type: ignore[attr-defined]  # an Input
        reply = await press(pilot, app, station, *"engine.bolt2_e = tightened", "enter")
        assert reply.accepted, reply.reason

        def shows_forced() -> bool:
            seen = snapshot_since(station, forced_at)
            return seen is not None and seen[1] == ["engine.bolt2_e"] and seen[0]["engine.bolt2_e"] == "tightened"

        await until(pilot, station, shows_forced, "the controller's state shows engine.bolt2_e forced")
        await until(pilot, station, lambda: str(app.table("state").shown.get("engine.bolt2_e", ("",) * 5)[3])
                    == "FORCED", "the console marks engine.bolt2_e forced")
        screenshot = Path(app.save_screenshot(filename="console.svg", path=str(tmp_path)))

        unforced_at = time.monotonic()
        app.table("state").select("engine.bolt2_e")
        undone = await press(pilot, app, station, "u")
        assert undone.accepted and undone.reason == "engine.bolt2_e is placed again"

        def shows_unforced() -> bool:
            seen = snapshot_since(station, unforced_at)
            return seen is not None and seen[1] == [] and seen[0]["engine.bolt2_e"] == "placed"

        await until(pilot, station, shows_unforced, "the controller's state shows engine.bolt2_e no longer forced")

        # A force outside the variable's domain is refused, with the domain.
        await pilot.press("f")
        app.query_one("#force").value = ""  # type: ignore[attr-defined]  # an Input
        refused = await press(pilot, app, station, *"ur.pos_m = nowhere", "enter")
        assert not refused.accepted
        assert refused.reason == "'nowhere' is outside the domain of ur.pos_m ({home, at_bolt1, at_bolt2, unknown})"

        # The controller logged every request in its event log, which the console shows.
        requests = [e for s in station.watch.statuses() for e in s.message.events if isinstance(e, RequestAnswered)]
        assert any(e.origin and (e.request, e.accepted, e.detail) == ("confirm", True, "human confirmed place_bolts")
                   for e in requests)

    svg = screenshot.read_text()
    assert svg.startswith("<svg")
    for title in ("Operations", "Plan", "Resources", "Global", "Events", "FORCED", "PlaceBolts"):
        assert title in svg, f"{title!r} is not in the screenshot"


async def test_reference_station_runs_to_completion_from_the_console(tmp_path: Path) -> None:
    """The operator's whole job: start the station, confirm each instruction, watch it finish."""
    never_confirms = ('type = "operator"\nmode = "emulate"\n', 'type = "operator"\nmode = "emulate"\ndelay = 3600\n')
    config = write_config(tmp_path, REFERENCE_STATION, prefix="console", replace=(never_confirms,))
    with Station(tmp_path, config=config, speed=5.0, hold=True) as station:
        station.start(timeout=60)
        app = console_for(station)
        tasks = msgspec.convert(station.model.resource_by_name["human"].parameters["tasks"], list[str])
        operations = [op.name for op in station.model.operations]
        confirmed: list[str] = []
        async with app.run_test(size=SCREEN) as pilot:
            await until(pilot, station, lambda: len(app.table("operations").shown) == len(operations),
                        "the console shows every operation")
            await until(pilot, station, lambda: len(app.table("resources").shown) == len(station.config.resources),
                        "the console shows every resource")
            await pilot.press("a")  # start all: one request per operation
            await until(pilot, station, lambda: len(app.replies) == len(operations), "an answer to every start")
            refused = [(request.operation, reply.reason) for request, reply in app.replies if not reply.accepted]
            assert not refused, refused
            deadline = time.monotonic() + 240  # ~1 min on 2 cores
            last_confirmed = None
            while not (app.feed.status is not None and app.feed.status.finished):
                assert time.monotonic() < deadline, f"the station did not finish: {station.describe()}"
                assert not station.dead(), f"{station.dead()} exited: {station.describe()}"
                values = app.state_view.values  # what the operator reads on the console
                task = values.get("human.instr_c")
                # Whatever stands is confirmed, as the operator would: a plan may ask for a task again (a detour
                # that fetches the nutrunner), which the model allows. The reply names the task confirmed.
                if task in tasks and (task != last_confirmed or not values.get("human.done_m")):
                    reply = await press(pilot, app, station, "c")
                    if reply.accepted:
                        last_confirmed = reply.reason.rsplit(" ", 1)[-1]
                        confirmed.append(last_confirmed)
                await pilot.pause(0.2)
            await until(pilot, station,
                        lambda: all(shown_op_state(app, name) == OperationState.FINISHED for name in operations),
                        "the console shows every operation finished")
        assert station.watch.finished()
        # The emulated operator never confirms: whatever an operator's confirmation records (the frame
        # placed, the bolts placed, ...) the console confirmed, in the order of the instructions. A
        # confirmation that records nothing (the pipe tightened) may still be pending when the last
        # operation finishes.
        operator = station.model.resource_by_name["human"]
        recording = {task for task in tasks
                     if len(operator.abilities[tasks.index(task)].transition("finished").written()) > 1}
        assert recording <= set(confirmed), f"confirmed {confirmed}; needed {sorted(recording)}"
        first_confirmations = list(dict.fromkeys(confirmed))
        assert first_confirmations == [task for task in tasks if task in confirmed], confirmed
