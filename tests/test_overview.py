"""The overview page's parts without a browser: the picture from statuses, the Gantt data, the read-only
reader, the [overview] section of hubs.toml, the viewer's access control and the web server's routes.
The page in a real browser against a running station: tests/test_overview_browser.py."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import msgspec
import pytest
from aiohttp.test_utils import TestClient, TestServer

from common.bus.memory_bus import MemoryBus, MemoryHub
from common.config.acl import access_control
from common.config.hubs_toml import ConfigError, load_station, parse_config
from common.config.overview import DEFAULT_BIND, parse_bind
from common.config.security import identity_of, roles_of
from common.model import OperationState
from common.wire.ctl import (
    HubGone,
    OperationInfo,
    PlanDetails,
    PlanInfo,
    PlanStepInfo,
    ProductionInfo,
    ResourceHealthInfo,
    StatusMessage,
    done_mask,
)
from common.wire.messages import encode
from controller.console.station import StationInfo
from controller.console.view import OperationClock
from controller.overview.feed import OverviewFeed
from controller.overview.picture import Severity, gantt, picture
from controller.overview.reader import StationReader
from controller.overview.web import make_app
from controller.timeline.model import Marker, MarkerKind, Period, Span, Timeline

ROOT = Path(__file__).resolve().parents[1]
FAULT_STATION = ROOT / "tests" / "fault_station" / "hubs.toml"


@pytest.fixture(scope="module")
def info() -> StationInfo:
    config, model = load_station(FAULT_STATION)
    return StationInfo.from_station(config, model)


def status(**fields: object) -> StatusMessage:
    base: dict[str, Any] = dict(station="fault_station", controller="ctl-1", time=100.0, uptime=12.0)
    base.update(fields)
    return StatusMessage(**base)


# --- the picture ---------------------------------------------------------------------------------

def test_picture_marks_only_what_is_abnormal(info: StationInfo) -> None:
    shown = picture("fault_station", status(
        operations=[OperationInfo("TightenBolt1", OperationState.FINISHED, since=3.0),
                    OperationInfo("TightenBolt2", OperationState.EXECUTING, since=5.0),
                    OperationInfo("TightenBolt3", OperationState.ERROR, error="no plan", since=9.0)],
        health=[ResourceHealthInfo("nr", "pi-tool", True, age=0.2),
                ResourceHealthInfo("ur", "ur10", False, reason="hub ur10 gone"),
                ResourceHealthInfo("nr2", "pi-tool", True, mirror_lag=2)]),
        None, info, OperationClock(), [HubGone("ur10")], silent_s=0.1)
    assert [(op.name, op.severity) for op in shown.operations] == [  # what is wrong first, then what runs
        ("TightenBolt3", Severity.ALARM), ("TightenBolt2", Severity.NORMAL), ("TightenBolt1", Severity.NORMAL)]
    assert shown.operations[1].in_state == "0:07"  # uptime 12 - since 5
    assert shown.operations[2].goal == "engine.bolt1_e == tightened"
    assert [(r.resource, r.health, r.severity) for r in shown.resources] == [
        ("nr", "ok", Severity.NORMAL), ("ur", "hub ur10 gone", Severity.ALARM), ("nr2", "ok", Severity.WARNING)]
    assert shown.resources[0].mode == "emulate" and shown.resources[2].mirror == "2 behind"
    assert shown.alarms == 2 and shown.connected and shown.severity is Severity.NORMAL
    assert [(e.text, e.severity) for e in shown.events] == [("hub ur10 gone", Severity.ALARM)]


def test_a_silent_or_absent_controller_is_an_alarm(info: StationInfo) -> None:
    nothing = picture("fault_station", None, None, info, OperationClock(), [], silent_s=None)
    assert not nothing.connected and nothing.severity is Severity.ALARM and "no status" in nothing.headline
    silent = picture("fault_station", status(), None, info, OperationClock(), [], silent_s=7.0)
    assert not silent.connected and silent.severity is Severity.ALARM and "silent for 7 s" in silent.headline


def test_plan_steps_say_what_they_wait_for_once_the_details_are_of_this_plan(info: StationInfo) -> None:
    plan = PlanInfo(id=4, goals=["engine.bolt1_e == tightened"], steps=2, done=done_mask([0], 2))
    details = PlanDetails(id=4, goals=plan.goals, current=True, steps=[
        PlanStepInfo("ur", "ur.move_home_at_bolt1", "deliberate", "ur.pos_m == home", True),
        PlanStepInfo("nr", "nr.start", "deliberate", "ur.pos_m == at_bolt1", False)])
    shown = picture("fault_station", status(plan=plan), details, info, OperationClock(), [], 0.0)
    assert shown.plan.summary.startswith("1/2 steps")
    assert [(s.number, s.done, s.waits_for) for s in shown.plan.steps] == [  # what is still to come first
        (2, False, "ur.pos_m == at_bolt1"), (1, True, "")]
    older = msgspec.structs.replace(details, id=3)
    assert picture("fault_station", status(plan=plan), older, info, OperationClock(), [], 0.0).plan.steps == []


def test_orders_are_shown_when_the_station_runs_orders(info: StationInfo) -> None:
    assert picture("fault_station", status(), None, info, OperationClock(), [], 0.0).production == ""
    shown = picture("fault_station", status(production=ProductionInfo(queued=3, done=1)), None, info,
                    OperationClock(), [], 0.0)
    assert shown.production == "no order, 3 queued, 1 done"


def test_gantt_lanes_by_index() -> None:
    timeline = Timeline(
        station="s", run="r1", end=10.0, resources=["nr", "ur"], operations=["TightenBolt1"],
        abilities=[Span("ur", "move", 1.0, 2.5, "done"), Span("nr", "run", 3.0, 10.0, "running")],
        operation_spans=[Span("TightenBolt1", "executing", 0.5, 10.0, "executing")],
        plans=[Marker(0.4, MarkerKind.PLAN, "start -> 4 steps")],
        faults=[Marker(6.0, MarkerKind.FAULT, "hub pi-tool gone", "pi-tool")],
        unhealthy=[Period("nr", 6.0, 10.0, "hub pi-tool gone")])
    drawn = gantt(timeline)
    assert drawn.lanes == ["nr", "ur", "TightenBolt1"] and drawn.resources == 2
    assert [(s.lane, s.label, s.outcome) for s in drawn.abilities] == [(1, "move", "done"), (0, "run", "running")]
    assert [(s.lane, s.outcome) for s in drawn.operations] == [(2, "executing")]
    assert [(s.lane, s.outcome) for s in drawn.unhealthy] == [(0, "hub pi-tool gone")]
    assert [(m.kind, m.lane) for m in drawn.markers] == [("plan", -1), ("fault", -1)]
    assert msgspec.json.decode(msgspec.json.encode(drawn))["abilities"][0] == [1, "move", 1.0, 2.5, "done"]


# --- the feed and the reader ---------------------------------------------------------------------

def test_reader_offers_nothing_that_writes() -> None:
    reader = StationReader(MemoryBus(MemoryHub()), load_station(FAULT_STATION)[0].keys)
    offered = {name for name in dir(reader) if not name.startswith("_")}
    assert offered == {"keys", "statuses", "full_status", "plan"}
    with pytest.raises(AttributeError):
        reader.bus  # type: ignore[attr-defined]  # noqa: B018


async def test_feed_follows_deltas_and_asks_for_the_whole_picture_it_missed(info: StationInfo) -> None:
    config, _ = load_station(FAULT_STATION)
    keys = config.keys
    hub = MemoryHub()
    controller = await MemoryBus(hub).open()
    full = status(seq=5, operations=[OperationInfo("TightenBolt1", OperationState.INITIAL)])
    asked: list[str] = []

    async def answer(request: object) -> bytes:
        asked.append(keys.ctl("status"))
        return encode(full)

    controller.declare_queryable(keys.ctl("status"), answer)
    feed = OverviewFeed(info, None)
    running = asyncio.create_task(feed.run(StationReader(await MemoryBus(hub).open(), keys)))
    try:
        async with asyncio.timeout(10):
            while feed.status is None:
                await asyncio.sleep(0.01)
        assert asked and feed.status.seq == 5
        controller.publish(keys.ctl("status"), encode(status(seq=6, full=False, operations=[
            OperationInfo("TightenBolt1", OperationState.EXECUTING, since=11.0)])))
        async with asyncio.timeout(10):
            while feed.picture().operations[0].state != OperationState.EXECUTING:
                await asyncio.sleep(0.01)
        assert feed.gantt.run == "" and "no recording" in feed.gantt.note
    finally:
        running.cancel()
        await asyncio.gather(running, return_exceptions=True)


# --- the web server --------------------------------------------------------------------------------

async def test_every_route_is_a_get_and_the_page_is_self_contained(info: StationInfo) -> None:
    feed = OverviewFeed(info, None)
    await feed.take(status(operations=[OperationInfo("TightenBolt1", OperationState.EXECUTING)]))
    async with TestClient(TestServer(make_app(feed))) as client:
        page = await client.get("/")
        text = await page.text()
        assert page.status == 200 and "form-action 'none'" in page.headers["Content-Security-Policy"]
        assert "<form" not in text and "<button" not in text and "<input" not in text
        assert "http://" not in text and "https://" not in text  # nothing fetched from elsewhere
        for static in ("/static/overview.js", "/static/overview.css"):
            response = await client.get(static)
            body = await response.text()
            assert response.status == 200 and "http://" not in body.replace("http://www.w3.org/2000/svg", "")
            assert "fetch(" not in body and "XMLHttpRequest" not in body and "WebSocket" not in body
        shown = await (await client.get("/picture.json")).json()
        assert shown["operations"][0]["state"] == "executing"
        for route in ("/", "/events", "/picture.json", "/gantt.json"):
            for method in ("POST", "PUT", "DELETE", "PATCH"):
                assert (await client.request(method, route)).status == 405, (method, route)


# --- hubs.toml and the access control ---------------------------------------------------------------

def test_overview_section_defaults_and_errors() -> None:
    text = FAULT_STATION.read_text()
    assert parse_config(text).overview.bind == DEFAULT_BIND
    assert parse_bind("0.0.0.0:9000").port == 9000 and parse_bind("[::1]:8470").host == "::1"
    assert parse_config(text + '\n[overview]\nbind = "0.0.0.0:9000"\n').overview.bind == "0.0.0.0:9000"
    unknown = text + '\n[overview]\ncolour = "grey"\n'
    with pytest.raises(ConfigError, match=rf"hubs.toml:{len(unknown.splitlines())}: overview.colour: unknown key"):
        parse_config(unknown, "hubs.toml")
    bad = text + '\n[overview]\nbind = "localhost"\nname = "ur10"\n'
    with pytest.raises(ConfigError) as caught:
        parse_config(bad, "hubs.toml")
    lines = bad.splitlines()
    problems = {p.key: (p.line, p.message) for p in caught.value.problems}
    assert problems["overview.bind"][0] == lines.index('bind = "localhost"') + 1
    assert "HOST:PORT" in problems["overview.bind"][1]
    assert problems["overview.name"][0] == lines.index('name = "ur10"') + 1
    with pytest.raises(ConfigError, match=r"hubs.toml:\d+: overview.bind: .*port '99999'"):
        parse_config(text + '\n[overview]\nbind = "127.0.0.1:99999"\n', "hubs.toml")
    with pytest.raises(ConfigError, match=r"overview.name: 'ur10' is already the name of a hub"):
        parse_config(text + '\n[overview]\nname = "ur10"\n', "hubs.toml")


def test_the_viewer_may_only_read() -> None:
    config, model = load_station(FAULT_STATION)
    keys = config.keys
    assert roles_of(config)["overview"] == "viewer" and identity_of(config, "overview").role == "viewer"
    acl = access_control(config, model)
    policy = next(p for p in acl["policies"] if p["subjects"] == ["viewer-overview"])
    rules = [r for r in acl["rules"] if r["id"] in policy["rules"]]
    allowed = {(m, k) for r in rules for m in r["messages"] for k in r["key_exprs"]}
    assert {m for m, _ in allowed} == {"query", "declare_subscriber", "declare_liveliness_subscriber",
                                       "liveliness_query"}
    assert {k for m, k in allowed if m == "query"} == {keys.ctl("status"), keys.all_plans}
