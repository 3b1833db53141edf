"""The server-sent events of both overview pages (controller/overview/web.py `stream_events`): the station's
page gets the picture on every change and the Gantt data only when it changed; the line's site page gets
the site picture on every change."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import msgspec
import pytest
from aiohttp import ClientResponse
from aiohttp.test_utils import TestClient, TestServer

from common.config.hubs_toml import load_station
from common.model import OperationState
from common.wire.ctl import OperationInfo, StatusMessage
from controller.console.station import StationInfo
from controller.overview import web
from controller.overview.feed import OverviewFeed
from controller.overview.picture import no_gantt
from controller.overview.site import SiteFeed, SitePicture, make_site_app
from controller.overview.web import make_app

FAULT_STATION = Path(__file__).resolve().parents[1] / "tests" / "fault_station" / "hubs.toml"
EVENT_WAIT_S = 30.0  # an event is written within REFRESH_S of a change; generous for a loaded machine


@pytest.fixture(autouse=True)
def no_keepalive(monkeypatch: pytest.MonkeyPatch) -> None:
    """A keep-alive resend between two changes would be an event the sequences below do not expect."""
    monkeypatch.setattr(web, "KEEPALIVE_S", 3600.0)


async def next_event(events: ClientResponse) -> tuple[str, Any]:
    async with asyncio.timeout(EVENT_WAIT_S):
        block = await events.content.readuntil(b"\n\n")
    name_line, data_line = block.decode().strip().split("\n")
    assert name_line.startswith("event: ") and data_line.startswith("data: ")
    return name_line.removeprefix("event: "), msgspec.json.decode(data_line.removeprefix("data: "))


def status(seq: int, operation_state: OperationState) -> StatusMessage:
    return StatusMessage(station="fault_station", controller="ctl-1", time=100.0 + seq, uptime=12.0, seq=seq,
                         operations=[OperationInfo("TightenBolt1", operation_state)])


async def test_the_station_page_gets_every_picture_and_the_gantt_data_when_it_changed() -> None:
    config, model = load_station(FAULT_STATION)
    feed = OverviewFeed(StationInfo.from_station(config, model), None)
    async with TestClient(TestServer(make_app(feed))) as client:
        events = await client.get("/events")
        assert events.headers["Content-Type"] == "text/event-stream"
        received = [await next_event(events), await next_event(events)]
        await feed.take(status(1, OperationState.EXECUTING))
        received.append(await next_event(events))
        feed.gantt = no_gantt("another run")
        await feed.take(status(2, OperationState.FINISHED))
        received += [await next_event(events), await next_event(events)]
        events.close()
    assert [name for name, _ in received] == ["picture", "gantt", "picture", "picture", "gantt"]
    assert [_operation_state(data) for name, data in received if name == "picture"] == [
        None, "executing", "finished"]
    assert [data["note"] for name, data in received if name == "gantt"] == [
        "reading the run's recording ...", "another run"]


def _operation_state(picture: Any) -> str | None:
    operations = picture["operations"]
    return operations[0]["state"] if operations else None


async def test_the_site_page_gets_every_site_picture() -> None:
    feed = SiteFeed("line")
    async with TestClient(TestServer(make_site_app(feed))) as client:
        events = await client.get("/events")
        first = await next_event(events)
        await feed.update(SitePicture("line", "1/2 products left the last station", [], []))
        second = await next_event(events)
        events.close()
    assert first == ("site", msgspec.to_builtins(SitePicture("line", "connecting to the stations ...", [], [])))
    assert second[0] == "site" and second[1]["headline"] == "1/2 products left the last station"
