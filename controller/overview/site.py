"""The site view: a read-only web page of a line of stations, one row per station (its state, current product,
cycle time, health, and whether it can be reached), served by `hubctl line up` and `hubctl line overview`.

It reuses the station overview's server (web.py: the same headers, Content-Security-Policy, server-sent
events and style sheet); what it shows is a `SitePicture`, made by whoever follows the stations (the line's
deploy/line/overview.py) and handed to a `SiteFeed`.

    GET /            the page (static/site.html, static/site.js, static/overview.css)
    GET /events      server-sent events: `site` (the SitePicture) whenever it changed, at most every REFRESH_S
    GET /site.json   the SitePicture now
"""

from __future__ import annotations

import asyncio
import enum

import msgspec
from aiohttp import web

from common.wire.orders import ParameterValue

from .picture import Severity
from .web import STATIC, _event, read_only_app, stream_events


class StationState(enum.StrEnum):
    WAITING = "waiting"  # no status yet
    IDLE = "idle"  # no product on the station
    WORKING = "working"  # a product's order runs
    UNREACHABLE = "unreachable"  # no status came for a while: its router, the link, or its controller is down


class SiteStation(msgspec.Struct, frozen=True):
    station: str
    state: StationState
    product: str  # "" when none
    cycle_s: float | None  # the last finished order's
    done: int  # orders it finished
    unhealthy: list[str]  # its unhealthy resources
    carried: dict[str, ParameterValue]  # the current product's state from the previous station
    severity: Severity


class SitePicture(msgspec.Struct, frozen=True):
    line: str
    headline: str  # e.g. "2/5 products left the last station"
    stations: list[SiteStation]
    unreachable: list[str]


def station_severity(state: StationState, unhealthy: list[str]) -> Severity:
    if state is StationState.UNREACHABLE:
        return Severity.ALARM
    return Severity.WARNING if unhealthy else Severity.NORMAL


class SiteFeed:
    """The newest SitePicture; event streams wait for the next one that differs."""

    def __init__(self, line: str) -> None:
        self.picture = SitePicture(line, "connecting to the stations ...", [], [])
        self.version = 0
        self._changed = asyncio.Condition()

    async def update(self, picture: SitePicture) -> None:
        if picture == self.picture:
            return
        async with self._changed:
            self.picture = picture
            self.version += 1
            self._changed.notify_all()

    async def changed(self, seen: int) -> int:
        async with self._changed:
            await self._changed.wait_for(lambda: self.version != seen)
            return self.version


SITE_FEED: web.AppKey[SiteFeed] = web.AppKey("site_feed", SiteFeed)


async def _index(_request: web.Request) -> web.FileResponse:
    return web.FileResponse(STATIC / "site.html")


async def _site(request: web.Request) -> web.Response:
    return web.Response(body=msgspec.json.encode(request.app[SITE_FEED].picture), content_type="application/json")


async def _events(request: web.Request) -> web.StreamResponse:
    feed = request.app[SITE_FEED]
    return await stream_events(request, feed.changed, lambda: [_event("site", msgspec.json.encode(feed.picture))])


def make_site_app(feed: SiteFeed) -> web.Application:
    """Every route a GET, as the station overview's: nothing here can act on the line."""
    app = read_only_app({"/": _index, "/events": _events, "/site.json": _site})
    app[SITE_FEED] = feed
    return app
