"""The console's panels without a station: rows from messages, the event feed, the force input, RowTable.sync."""

from __future__ import annotations

import pytest
from textual.app import App, ComposeResult

from common.config.hubs_toml import load_station
from common.config.modes import DeviceMode
from common.model import Kind, OperationState
from common.wire.ctl import (
    ConsoleEvent,
    ControllerChanged,
    FasterPlan,
    ForbiddenState,
    ForbiddenStateCleared,
    HoldReleased,
    HubAlive,
    HubGone,
    MirrorsMissing,
    NoPlanFound,
    OperationInfo,
    OrderDone,
    PlanFound,
    PlanKept,
    PlannedAlone,
    ProductionInfo,
    Recovered,
    ReplanCause,
    Replanned,
    ReplanReason,
    RequestAnswered,
    ResourceHealthInfo,
    ShorterPlan,
    StateSnapshot,
    StatusMessage,
    Unhealthy,
)
from common.wire.messages import decode, encode
from common.wire.orders import Order, OrderState
from controller.console.station import StationInfo
from controller.console.table import RowTable
from controller.console.view import (
    RECENT_S,
    EventFeed,
    OperationClock,
    StateFilter,
    StateView,
    event_text,
    parse_force,
    production_summary,
    split_override,
)
from deploy.cli import build_parser
from tests.fault_station.harness import ROOT


def status(events: list[ConsoleEvent], *, controller: str = "ctl-1", health: list[ResourceHealthInfo] | None = None,
           operations: list[OperationInfo] | None = None, uptime: float = 0.0) -> StatusMessage:
    return StatusMessage(station="s", controller=controller, time=0.0, uptime=uptime, operations=operations or [],
                         health=health or [], plans=0, replans=0, no_plans=0, abilities=0,
                         events=events)


def test_event_feed_shows_each_event_of_the_sliding_window_once() -> None:
    feed = EventFeed()
    a, b, c, d, x = (HubAlive(hub) for hub in "abcdx")
    assert feed.new(status([a, b])) == [a, b]
    assert feed.new(status([a, b])) == []
    assert feed.new(status([b, c, d])) == [c, d]  # a slid out of the window
    assert feed.new(status([x], controller="ctl-2")) == [ControllerChanged("ctl-2", "ctl-1"), x]


def test_event_feed_notes_the_watchdogs_verdicts() -> None:
    feed = EventFeed()
    ok, lost = ResourceHealthInfo("nr", "pi-tool", True), ResourceHealthInfo("nr", "pi-tool", False, "hub gone")
    assert feed.new(status([], health=[ok])) == []
    assert feed.new(status([], health=[lost])) == [Unhealthy("nr", "hub gone")]
    assert feed.new(status([], health=[lost])) == []
    assert feed.new(status([], health=[ok])) == [Recovered("nr")]


# Each kind of event as the controller logs it, and the line the console shows for it.
EVENT_LINES: list[tuple[ConsoleEvent, str, str]] = [
    (Replanned(ReplanCause(ReplanReason.LEFT_PLAN, "g.level_m is 'high', expected 'low'")),
     "replan: the state left the plan: g.level_m is 'high', expected 'low'", "yellow"),
    (Replanned(ReplanCause(ReplanReason.HEALTH_CHANGED, "nr, ur")),
     "replan: resource health changed (disabled: nr, ur)", "yellow"),
    (Replanned(ReplanCause(ReplanReason.STOPPED_BY_OPERATOR, "PlaceBolts")),
     "replan: operation PlaceBolts stopped by the operator", "yellow"),
    (Replanned(ReplanCause(ReplanReason.GOALS_CHANGED)), "replan: goals changed", "yellow"),
    (PlanKept(3, ReplanCause(ReplanReason.LEFT_PLAN, "cam.zone_m is 'robot', expected 'none'")),
     "plan kept: 3 steps still reach the goals (the state left the plan: cam.zone_m is 'robot', expected 'none')", ""),
    (ShorterPlan(12, 15, "astar"), "shorter plan taken: 12 steps left instead of 15 (astar)", ""),
    (FasterPlan(11, 8.0, 11.0, "astar, retimed"),
     "faster plan taken: 11 steps predicted to take 8.0 s instead of 11.0 s (astar, retimed)", ""),
    (PlannedAlone("RobotHome", 3, "expansion limit"),
     "planned RobotHome alone: 3 goals together were not solved within the budget (expansion limit)", ""),
    (NoPlanFound(["LampOn", "LampOff"], True, "forbidden"), "no plan (unreachable) for LampOn, LampOff: forbidden",
     "bold red"),
    (NoPlanFound(["LampOn"], False, "budget"), "no plan (not found in time) for LampOn: budget", "bold red"),
    (PlanFound("LampOn", 4), "plan found for LampOn after 4 attempt(s) without one", ""),
    (HubAlive("pi-tool"), "hub pi-tool alive", ""),
    (HubGone("pi-tool"), "hub pi-tool gone", "bold red"),
    (MirrorsMissing({"pi-tool": ["nr", "rfid"], "decs": ["ur"]}),
     "start: no mirror from hub decs: ur; hub pi-tool: nr, rfid: held, no command until their mirrors arrive", ""),
    (HoldReleased("rsp", "its mirror"), "rsp no longer held: its commands resume from its mirror", ""),
    (ForbiddenState("tool_released_outside_its_slot", {"rsp.lock_c": False, "rsp.tool_m": "nutrunner"}),
     "forbidden state: tool_released_outside_its_slot holds (rsp.lock_c = false, rsp.tool_m = nutrunner): "
     "deliberate transitions stopped", "bold red"),
    (ForbiddenStateCleared("tool_released_outside_its_slot"),
     "forbidden state cleared: tool_released_outside_its_slot no longer holds", "green"),
    (RequestAnswered("start Op", False, "Op is finished: reset it to run it again", "ann@decs"),
     "console (ann@decs): start Op refused: Op is finished: reset it to run it again", "cyan"),
    (RequestAnswered("pause", True), "console: pause accepted", "cyan"),
    (Unhealthy("nr", "hub gone"), "watchdog: nr unhealthy: hub gone", "bold red"),
    (Recovered("nr"), "watchdog: nr recovered", "green"),
    (ControllerChanged("ctl-2", "ctl-1"), "controller ctl-2 (was ctl-1)", ""),
]


@pytest.mark.parametrize(("event", "line", "style"), EVENT_LINES)
def test_each_event_reads_as_before_survives_the_wire_and_is_styled_by_its_kind(event: ConsoleEvent, line: str,
                                                                                style: str) -> None:
    assert event.text == line
    received = decode(encode(status([event])), StatusMessage).events
    assert received == [event] and type(received[0]) is type(event)
    shown = event_text(received[0])
    assert (shown.plain, str(shown.style)) == (line, style)


def test_operation_clock_times_the_changes_the_controller_does_not() -> None:
    clock = OperationClock()
    executing, finished, initial = OperationState.EXECUTING, OperationState.FINISHED, OperationState.INITIAL
    assert clock.since(OperationInfo("Op", executing, since=5.0), uptime=9.0) == 5.0
    assert clock.since(OperationInfo("Op", finished, since=12.0), uptime=12.5) == 12.0  # timed by the controller
    assert clock.since(OperationInfo("Op", initial, since=12.0), uptime=20.0) == 20.0  # a reset: seen at 20 s
    assert clock.since(OperationInfo("Op", initial, since=12.0), uptime=30.0) == 20.0


def test_state_view_filters_by_path_kind_and_recent_change() -> None:
    kinds = {"nr.run_c": Kind.COMMAND, "nr.run_m": Kind.MEASURED, "engine.bolt1_e": Kind.ESTIMATED}
    view = StateView(kinds)
    view.update(StateSnapshot(time=1.0, values={"nr.run_c": False, "nr.run_m": False, "engine.bolt1_e": "placed"}),
                now=100.0)
    assert view.changed_at == {}  # the first snapshot tells nothing about changes
    view.update(StateSnapshot(time=2.0, values={"nr.run_c": True, "nr.run_m": False, "engine.bolt1_e": "placed"},
                              forced=["nr.run_c"]), now=101.0)
    assert list(view.rows(StateFilter(), now=102.0)) == ["nr.run_c", "nr.run_m", "engine.bolt1_e"]
    assert list(view.rows(StateFilter(text="NR."), now=102.0)) == ["nr.run_c", "nr.run_m"]
    assert list(view.rows(StateFilter(kind=Kind.ESTIMATED), now=102.0)) == ["engine.bolt1_e"]
    assert list(view.rows(StateFilter(recent=True), now=102.0)) == ["nr.run_c"]
    assert list(view.rows(StateFilter(recent=True), now=101.0 + RECENT_S + 1)) == []
    row = view.rows(StateFilter(), now=102.0)["nr.run_c"]
    assert (row[0], row[1], str(row[2]), str(row[3]), row[4]) == ("nr.run_c", "command", "true", "FORCED", "1 s ago")
    assert StateFilter().next_kind().next_kind().kind is Kind.ESTIMATED


@pytest.mark.parametrize(("text", "expected"), [
    ("nr.run_c = true", ("nr.run_c", True)),
    ("ur.pos_m := home", ("ur.pos_m", "home")),
    ("  lift.level_c=2 ", ("lift.level_c", 2)),
])
def test_force_input_reads_the_model_notation(text: str, expected: tuple[str, object]) -> None:
    assert parse_force(text) == expected


def test_force_input_takes_an_explicit_override() -> None:
    assert split_override("rsp.lock_c = false !override") == ("rsp.lock_c = false", True)
    assert split_override(" rsp.lock_c = false ") == ("rsp.lock_c = false", False)


@pytest.mark.parametrize(("text", "message"), [
    ("nr.run_c", "expected `path = value`"),
    ("nr.run_c = ur.pos_m", "force takes a value, not another variable (ur.pos_m)"),
])
def test_force_input_says_what_is_wrong(text: str, message: str) -> None:
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        parse_force(text)


class TableApp(App[None]):
    def compose(self) -> ComposeResult:
        yield RowTable(("key", "value"), title="t", id="t")


async def test_row_table_changes_only_what_differs_and_keeps_the_cursor_on_its_row() -> None:
    app = TableApp()
    async with app.run_test() as pilot:
        table = app.query_one(RowTable)
        assert table.sync({"a": ("a", "1"), "b": ("b", "2")}) == 2  # rows added
        assert table.sync({"a": ("a", "1"), "b": ("b", "3")}) == 1  # one cell
        assert table.sync({"a": ("a", "1"), "b": ("b", "3")}) == 0
        assert table.sync({"a": ("a", "1"), "b": ("b", "3"), "c": ("c", "4")}) == 1  # appended
        table.select("c")
        assert table.sync({"a": ("a", "1"), "c": ("c", "4")}) == 1  # removed
        assert table.sync({"c": ("c", "4"), "a": ("a", "a much wider value")}) == 2  # reordered: rebuilt
        await pilot.pause()
        assert table.selected_key() == "c"
        assert [table.get_row_at(i)[1] for i in range(table.row_count)] == ["4", "a much wider value"]


def test_console_finds_the_controller_from_hubs_toml_and_parses_its_options() -> None:
    config, model = load_station(ROOT / "hubs.toml")
    info = StationInfo.from_station(config, model)
    assert info.default_connect == ("tcp/127.0.0.1:7447",)  # the controller listens on 0.0.0.0:7447
    assert info.kinds["nr.run_c"] is Kind.COMMAND and info.modes["nr"] is DeviceMode.EMULATE
    assert info.goals["TightenBolt7"] == "engine.bolt7_e == tightened"
    args = build_parser().parse_args(["console", "--connect", "tcp/decs.local:7447", "--listen", "none"])
    assert (args.connect, args.listen, args.config) == (["tcp/decs.local:7447"], "none", "hubs.toml")


def test_resource_rows_show_health_and_a_note_about_another_controller() -> None:
    from controller.console.view import resource_rows

    info = StationInfo(station="s", kinds={})
    health = [ResourceHealthInfo("nr", "pi-tool", True, age=0.1),
              ResourceHealthInfo("ur", "ur10", True, age=0.1, note="command seq 9 from intruder refused"),
              ResourceHealthInfo("lift", "pi-tool", False, "hub gone")]
    rows = resource_rows(status([], health=health), info, {})
    text = {resource: " ".join(str(cell) for cell in row) for resource, row in rows.items()}
    assert "ok" in text["nr"] and "intruder" not in text["nr"]
    assert "ok (command seq 9 from intruder refused)" in text["ur"]
    assert "hub gone" in text["lift"]


def test_the_status_line_shows_the_current_order_the_queue_and_the_last_cycles() -> None:
    assert production_summary(None) == ""  # a station without orders says nothing of them
    running = Order(id=3, product_id="engine-3", variant="light", state=OrderState.RUNNING)
    done = [OrderDone(1, "engine-1", "full", 0.0, 36.5), OrderDone(2, "engine-2", "light", 36.5, 62.3)]
    summary = production_summary(ProductionInfo(current=running, queued=2, done=2, recent=done))
    assert summary == "order 3 engine-3 (light), 2 queued, 2 done; last cycles: full 36.5 s, light 25.8 s"
    assert production_summary(ProductionInfo(queued=0, done=5)) == "no order, 0 queued, 5 done"
