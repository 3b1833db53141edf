"""The operator console: `hubctl console`, a terminal UI over Zenoh (works over SSH on the controller PC).

Panels: operations (state, goal, time in state, error), the current plan (each step and
the guard it waits for), resources (hub, mode, health, state age, mirror, self-test),
the global state (filtered by path, kind, recently changed; forced values marked) and
the event log (the controller's: replans, faults, requests; and the watchdog's verdicts).
`t` shows the current run's timeline instead (a text Gantt chart, gantt.py, of the newest
recording in `[controller.recording] dir`: the console runs on the controller PC).

Every action is a request to the controller, answered accepted or refused with the
reason (controller/requests.py says what each one does): `s` start, `a` start every
operation not started, `x` stop, `r` reset (the operation under the cursor), `p` pause /
resume, `c` operator confirm, `f` force (`path = value`), `u` unforce (the variable under
the cursor), `/` filter, `k` kind, `n` recently changed, `q` quit.

The screen is redrawn at most `REFRESH_S` apart and only when something arrived; the
tables change only the cells that differ (table.py), so 500 resources cost
what changes, not what exists.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections import deque
from collections.abc import Sequence
from pathlib import Path

from rich.text import Text
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import Grid, Vertical, VerticalScroll
from textual.css.query import NoMatches
from textual.widgets import Footer, Header, Input, RichLog, Static
from textual.worker import Worker, WorkerState

from common.config.modes import NetworkMode
from common.model import Model, OperationState
from common.wire.ctl import ConsoleReply, ConsoleRequest, StatusMessage
from controller.recording.writer import recording_dir
from controller.timeline.model import Timeline

from .gantt import current_timeline, gantt_lines
from .link import ConsoleLink, Feed
from .station import StationInfo
from .table import RowTable
from .view import (
    OPERATION_COLUMNS,
    PLAN_COLUMNS,
    RESOURCE_COLUMNS,
    STATE_COLUMNS,
    EventFeed,
    OperationClock,
    StateFilter,
    StateView,
    duration,
    event_text,
    operation_rows,
    parse_force,
    plan_rows,
    plan_summary,
    production_summary,
    resource_rows,
    split_override,
)

REFRESH_S = 0.3  # at most ~3 redraws a second: what a person can read
CLOCK_S = 1.0  # clocks on screen (time in state, changed ago) tick in whole seconds
SILENT_AFTER_S = 2.0  # the controller publishes its status every 0.25 s
TIMELINE_S = 2.0  # the timeline panel reads the run's recording again this often while it is shown


class ConsoleApp(App[None]):
    TITLE = "statehub console"
    CSS = """
    #panels { grid-size: 2 3; grid-rows: 3fr 3fr 2fr; grid-columns: 1fr 1fr; height: 1fr; }
    RowTable, #state-panel, #events { border: round $primary; height: 100%; }
    #state-panel RowTable { border: none; height: 1fr; }
    #filter { border: none; height: 1; padding: 0 1; }
    #events { column-span: 2; }
    #statusline { height: 1; padding: 0 1; background: $boost; }
    #force { display: none; }
    #force.shown { display: block; }
    #timeline-panel { display: none; border: round $primary; height: 1fr; }
    #timeline-panel.shown { display: block; }
    #panels.hidden { display: none; }
    """
    BINDINGS = [
        Binding("s", "start", "start"),
        Binding("a", "start_all", "start all"),
        Binding("x", "stop", "stop"),
        Binding("r", "reset", "reset"),
        Binding("p", "pause", "pause/resume"),
        Binding("c", "confirm", "confirm"),
        Binding("f", "force", "force"),
        Binding("u", "unforce", "unforce"),
        Binding("slash", "filter", "filter"),
        Binding("k", "kind", "kind"),
        Binding("n", "recent", "recent"),
        Binding("t", "timeline", "timeline"),
        Binding("escape", "leave_input", "back", show=False),
        Binding("q", "quit", "quit"),
    ]

    def __init__(self, info: StationInfo, feed: Feed, *, refresh_s: float = REFRESH_S) -> None:
        super().__init__()
        self.info = info
        self.feed = feed
        self.refresh_s = refresh_s
        self.sub_title = info.station
        self.state_filter = StateFilter()
        self.state_view = StateView(info.kinds)
        self.clock = OperationClock()
        self.events = EventFeed()
        self.replies: list[tuple[ConsoleRequest, ConsoleReply]] = []
        self.redraws = 0  # table redraws, and what the last one cost (tests/bench/bench_console.py)
        self.last_redraw_s = 0.0
        self.last_changed = 0
        self._drawn_version = -1
        self._drawn_at = 0.0
        self._status_seen_at: float | None = None
        self._status_seen: StatusMessage | None = None
        self._reply_line = Text("")
        self.log_lines: deque[str] = deque(maxlen=1000)  # from logging, any thread; drained by redraw
        self.timeline: Timeline | None = None  # the current run's, from its recording (key t)
        self._timeline_models: dict[str, Model] = {}

    # --- layout --------------------------------------------------------------------------------
    def compose(self) -> ComposeResult:
        yield Header()
        with Grid(id="panels"):
            yield RowTable(OPERATION_COLUMNS, title="Operations", id="operations")
            yield RowTable(PLAN_COLUMNS, title="Plan", id="plan")
            yield RowTable(RESOURCE_COLUMNS, title="Resources", id="resources")
            with Vertical(id="state-panel"):
                yield Input(placeholder="filter by path (/), kind (k), recently changed (n)", id="filter")
                yield RowTable(STATE_COLUMNS, title="", id="state")
            yield RichLog(id="events", max_lines=5000, wrap=True)
        with VerticalScroll(id="timeline-panel"):
            yield Static(id="timeline")
        yield Static(id="statusline")
        yield Input(placeholder="force: path = value [!override] (Enter forces, Esc cancels)", id="force")
        yield Footer()

    def on_mount(self) -> None:
        self.query_one("#events", RichLog).border_title = "Events"
        self._update_state_title()
        self.run_worker(self.feed.run(), name="bus", group="bus", exit_on_error=False)
        self.set_interval(self.refresh_s, self.redraw)
        self.set_interval(TIMELINE_S, self._timeline_due)
        self.table("operations").focus()

    def table(self, name: str) -> RowTable:
        return self.query_one(f"#{name}", RowTable)

    # --- drawing -------------------------------------------------------------------------------
    def redraw(self, *, force: bool = False) -> None:
        with contextlib.suppress(NoMatches):  # the timer fired while the app closes: its widgets are gone
            self._redraw(force)

    def _redraw(self, force: bool) -> None:
        now = time.monotonic()
        feed = self.feed
        fresh = feed.version != self._drawn_version
        if fresh or force or now - self._drawn_at >= CLOCK_S:
            began = time.perf_counter()
            self.last_changed = self._draw_tables(now)
            self.last_redraw_s = time.perf_counter() - began
            self.redraws += 1
            self._drawn_version, self._drawn_at = feed.version, now
        while self.log_lines:
            self.query_one("#events", RichLog).write(Text(self.log_lines.popleft(), "yellow"))
        self._draw_statusline(now)

    def _draw_tables(self, now: float) -> int:
        feed = self.feed
        status = feed.status
        changed = 0
        if status is not None:
            if status is not self._status_seen:
                self._status_seen, self._status_seen_at = status, now
                log = self.query_one("#events", RichLog)
                for event in self.events.new(status):
                    log.write(event_text(event))
            changed += self.table("operations").sync(operation_rows(status, self.info, self.clock))
            changed += self.table("plan").sync(plan_rows(status.plan, feed.plan))
            self.table("plan").border_subtitle = plan_summary(status.plan, status.cycle)
            changed += self.table("resources").sync(resource_rows(status, self.info, feed.selftests))
        if feed.snapshot is not None:
            self.state_view.update(feed.snapshot, now)
        state_rows = self.state_view.rows(self.state_filter, now)
        changed += self.table("state").sync(state_rows)
        self.query_one("#state-panel").border_subtitle = f"{len(state_rows)} of {len(self.state_view.values)}"
        return changed

    def _draw_statusline(self, now: float) -> None:
        status = self._status_seen
        line = Text()
        if status is None:
            line.append(f"waiting for the controller of {self.info.station}", "yellow")
        else:
            silent = now - (self._status_seen_at or now)
            done = sum(1 for op in status.operations if op.state is OperationState.FINISHED)
            line.append(f"controller {status.controller}, up {duration(status.uptime)}")
            if silent > SILENT_AFTER_S:
                line.append(f"  SILENT for {duration(silent)}", "bold red")
            if status.paused:
                line.append("  PAUSED", "bold yellow")
            if status.finished:
                line.append("  FINISHED", "bold green")
            line.append(f"  operations {done}/{len(status.operations)}, plans {status.plans}, "
                        f"replans {status.replans}, no plan {status.no_plans}")
            orders = production_summary(status.production)
            if orders:
                line.append(f"  |  {orders}")
        if self._reply_line:
            line.append("  |  ")
            line.append_text(self._reply_line)
        self.query_one("#statusline", Static).update(line)

    def _update_state_title(self) -> None:
        self.query_one("#state-panel").border_title = f"Global state: {self.state_filter.describe()}"

    # --- requests ------------------------------------------------------------------------------
    def ask(self, *requests: ConsoleRequest) -> None:
        """Send the requests one after the other (in the background), showing each answer."""
        self.run_worker(self._ask(requests), group="requests")

    async def _ask(self, requests: Sequence[ConsoleRequest]) -> None:
        refused = 0
        for request in requests:
            reply = await self.feed.request(request)
            self.replies.append((request, reply))
            refused += not reply.accepted
            if len(requests) == 1:
                self.show_reply(request, reply)
        if len(requests) > 1:
            summary = ConsoleReply(accepted=refused < len(requests),
                                   reason=f"{len(requests) - refused} accepted, {refused} refused")
            self.show_reply(requests[0], summary, what=f"{requests[0].action} {len(requests)} operations")

    def show_reply(self, request: ConsoleRequest, reply: ConsoleReply, what: str | None = None) -> None:
        what = what or request.describe()
        if reply.accepted:
            self._reply_line = Text(f"{what}: accepted" + (f" ({reply.reason})" if reply.reason else ""), "green")
        else:
            self._reply_line = Text(f"{what}: REFUSED: {reply.reason}", "bold red")
        self.notify(self._reply_line.plain, severity="information" if reply.accepted else "error")
        self._draw_statusline(time.monotonic())

    def say(self, message: str) -> None:
        """A problem found before asking (nothing selected, a typo in the force input)."""
        self._reply_line = Text(message, "yellow")
        self._draw_statusline(time.monotonic())

    def _selected_operation(self) -> str | None:
        name = self.table("operations").selected_key()
        if name is None:
            self.say("no operation selected: move the cursor in Operations")
        return name

    # --- actions -------------------------------------------------------------------------------
    def _operation_action(self, action: str) -> None:
        name = self._selected_operation()
        if name is not None:
            self.ask(ConsoleRequest(action=action, operation=name))

    def action_start(self) -> None:
        self._operation_action("start")

    def action_stop(self) -> None:
        self._operation_action("stop")

    def action_reset(self) -> None:
        self._operation_action("reset")

    def action_start_all(self) -> None:
        status = self.feed.status
        operations = status.operations if status is not None else []
        names = [op.name for op in operations if op.state is OperationState.INITIAL]
        if not names:
            self.say("no operation in initial state to start")
            return
        self.ask(*(ConsoleRequest(action="start", operation=name) for name in names))

    def action_pause(self) -> None:
        status = self.feed.status
        self.ask(ConsoleRequest(action="resume" if status is not None and status.paused else "pause"))

    def action_confirm(self) -> None:
        self.ask(ConsoleRequest(action="confirm"))

    def action_force(self) -> None:
        field = self.query_one("#force", Input)
        state = self.table("state")
        selected = state.selected_key() if self.focused is state else None  # the variable the operator is on
        if selected is not None and not field.value:
            field.value = f"{selected} = "
        field.add_class("shown")
        field.focus()
        field.cursor_position = len(field.value)

    def action_unforce(self) -> None:
        path = self.table("state").selected_key()
        if path is None:
            self.say("no variable selected: move the cursor in Global state")
            return
        self.ask(ConsoleRequest(action="unforce", path=path))

    def action_filter(self) -> None:
        self.query_one("#filter", Input).focus()

    def action_kind(self) -> None:
        self._set_filter(self.state_filter.next_kind())

    def action_recent(self) -> None:
        f = self.state_filter
        self._set_filter(StateFilter(f.text, f.kind, not f.recent))

    def action_timeline(self) -> None:
        """Show the current run's timeline instead of the panels (its recording, read on this host), or back."""
        panel = self.query_one("#timeline-panel")
        shown = not panel.has_class("shown")
        panel.set_class(shown, "shown")
        self.query_one("#panels").set_class(shown, "hidden")
        if shown:
            self._timeline_due()

    def _timeline_due(self) -> None:
        with contextlib.suppress(NoMatches):
            if self.query_one("#timeline-panel").has_class("shown"):
                self.run_worker(self._load_timeline(), group="timeline", exclusive=True)

    async def _load_timeline(self) -> None:
        directory = recording_dir(self.info.recordings or "var/runs")
        try:  # SQLite and the model: off the loop
            self.timeline = await asyncio.to_thread(current_timeline, directory, self._timeline_models)
        except Exception as exc:  # a recording being rotated, a model that does not load: said, not fatal
            self.query_one("#timeline", Static).update(Text(f"timeline: {type(exc).__name__}: {exc}", "yellow"))
            return
        self.show_timeline(directory)

    def show_timeline(self, directory: Path) -> None:
        panel = self.query_one("#timeline-panel")
        if self.timeline is None:
            panel.border_title = "Timeline"
            self.query_one("#timeline", Static).update(Text(f"no run recorded in {directory}", "yellow"))
            return
        panel.border_title = f"Timeline of run {self.timeline.run} ({directory}; t: back to the panels)"
        lines = gantt_lines(self.timeline, max(40, panel.size.width - 4))
        self.query_one("#timeline", Static).update(Text("\n").join(lines))

    def action_leave_input(self) -> None:
        field = self.query_one("#force", Input)
        field.remove_class("shown")
        field.value = ""
        self.table("operations").focus()

    def _set_filter(self, chosen: StateFilter) -> None:
        self.state_filter = chosen
        self._update_state_title()
        self.redraw(force=True)

    def on_input_changed(self, event: Input.Changed) -> None:
        if event.input.id == "filter":
            # Applied by the next redraw, not per keystroke: a new filter may rebuild a table of thousands of rows.
            f = self.state_filter
            self.state_filter = StateFilter(event.value.strip(), f.kind, f.recent)
            self._update_state_title()
            self._drawn_version = -1

    def on_worker_state_changed(self, event: Worker.StateChanged) -> None:
        if event.worker.name == "bus" and event.state in (WorkerState.ERROR, WorkerState.SUCCESS):
            error = event.worker.error
            self.log_lines.append(f"console: the bus closed{f': {error}' if error else ''}")
            self.say(f"disconnected from the station's bus{f': {error}' if error else ''}")

    def on_input_submitted(self, event: Input.Submitted) -> None:
        if event.input.id == "filter":
            self.table("state").focus()
            return
        if event.input.id != "force":
            return
        text = event.value.strip()
        self.action_leave_input()
        if not text:
            return
        text, override = split_override(text)
        try:
            path, value = parse_force(text)
        except ValueError as exc:
            self.say(f"force: {exc}")
            return
        self.ask(ConsoleRequest(action="force", path=path, value=value, override=override))


class _ToEventLog(logging.Handler):
    """The console owns the terminal: warnings (its own and zenoh's, from any thread) go to its event log."""

    def __init__(self, app: ConsoleApp) -> None:
        super().__init__(logging.WARNING)
        self.app = app

    def emit(self, record: logging.LogRecord) -> None:
        self.app.log_lines.append(f"console: {record.getMessage()}")  # deque.append is thread-safe


def run_console(config: str, connect: Sequence[str] = (), listen: Sequence[str] = ("tcp/0.0.0.0:0",), *,
                operator: str | None = None, certs: str | None = None) -> int:
    """`operator`: whose certificate the console presents in tls mode (default: the first of
    [security] operators); `certs`: the certificate directory."""
    from common.bus.station_net import station_zenoh_config
    from common.config.hubs_toml import NetworkConfig, load_station
    from common.config.security import operator_identity

    station, model = load_station(config)
    info = StationInfo.from_station(station, model)
    endpoints = list(connect) or list(info.default_connect)
    network = NetworkConfig(mode=NetworkMode.PEER, listen=list(listen), connect=endpoints, lease_ms=info.lease_ms)
    zconfig = station_zenoh_config(station, model, operator_identity(station, operator), network, certs=certs)
    link = ConsoleLink(info.station, endpoints, listen=listen, lease_ms=info.lease_ms, zconfig=zconfig)
    app = ConsoleApp(info, link)
    root = logging.getLogger()
    root.handlers[:] = [_ToEventLog(app)]
    root.setLevel(logging.WARNING)
    app.run()
    return 0
