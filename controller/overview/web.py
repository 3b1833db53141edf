"""The overview's web server (aiohttp): one page, its static files, and its live data. Nothing it serves acts.

    GET /              the page (static/index.html; its script and style beside it, nothing from the internet)
    GET /events        server-sent events: `picture` (the station, controller/overview/picture.py) whenever it
                       changed, at most every REFRESH_S, and `gantt` (the run's timeline) when it changed
    GET /picture.json  the picture now; GET /gantt.json the Gantt data now (for scripts and curl)

Every route is a GET: there is no handler that could take an action, whatever a page sent. The
Content-Security-Policy says the same to the browser (no form may be submitted, no script or style
from elsewhere, no connection but to this server).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable, Callable, Iterable, Iterator, Mapping
from pathlib import Path

import msgspec
from aiohttp import web

from .feed import OverviewFeed

STATIC = Path(__file__).with_name("static")
REFRESH_S = 0.3  # at most ~3 pictures a second: what a person can read
KEEPALIVE_S = 15.0  # a comment line this often keeps proxies from closing a quiet stream
FEED: web.AppKey[OverviewFeed] = web.AppKey("feed", OverviewFeed)
POLICY = ("default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; connect-src 'self'; "
          "form-action 'none'; frame-ancestors 'none'; base-uri 'none'")


Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


@web.middleware
async def _headers(request: web.Request, handler: Handler) -> web.StreamResponse:
    response = await handler(request)
    response.headers["Content-Security-Policy"] = POLICY
    response.headers["Cache-Control"] = "no-store"
    response.headers["X-Content-Type-Options"] = "nosniff"
    return response


async def _index(_request: web.Request) -> web.FileResponse:
    return web.FileResponse(STATIC / "index.html")


async def _picture(request: web.Request) -> web.Response:
    return web.Response(body=msgspec.json.encode(request.app[FEED].picture()), content_type="application/json")


async def _gantt(request: web.Request) -> web.Response:
    return web.Response(body=msgspec.json.encode(request.app[FEED].gantt), content_type="application/json")


def _event(name: str, data: bytes) -> bytes:
    return b"event: " + name.encode() + b"\ndata: " + data + b"\n\n"


async def stream_events(request: web.Request, changed: Callable[[int], Awaitable[int]],
                        due: Callable[[], Iterable[bytes]]) -> web.StreamResponse:
    """Server-sent events until the page goes away: `due()` (events made with `_event`) whenever `changed(seen)`
    says a version other than the one seen came, at most every REFRESH_S, and at least every KEEPALIVE_S."""
    response = web.StreamResponse(headers={"Content-Type": "text/event-stream"})
    await response.prepare(request)
    seen = -1
    with contextlib.suppress(ConnectionResetError, asyncio.CancelledError):
        while True:
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(KEEPALIVE_S):
                    seen = await changed(seen)
            for event in due():
                await response.write(event)
            await asyncio.sleep(REFRESH_S)
    return response


async def _events(request: web.Request) -> web.StreamResponse:
    feed = request.app[FEED]
    sent_gantt: object = None  # the Gantt data this stream sent last: it is sent again only when it changed

    def due() -> Iterator[bytes]:
        nonlocal sent_gantt
        yield _event("picture", msgspec.json.encode(feed.picture()))
        if feed.gantt is not sent_gantt:
            sent_gantt = feed.gantt
            yield _event("gantt", msgspec.json.encode(feed.gantt))

    return await stream_events(request, feed.changed, due)


def read_only_app(gets: Mapping[str, Handler]) -> web.Application:
    """An app answering only GETs: `gets` (path -> handler) and the static files, with this module's headers."""
    app = web.Application(middlewares=[_headers])
    for path, handler in gets.items():
        app.router.add_get(path, handler)
    app.router.add_static("/static/", STATIC, follow_symlinks=False)
    return app


def make_app(feed: OverviewFeed) -> web.Application:
    app = read_only_app({"/": _index, "/events": _events, "/picture.json": _picture, "/gantt.json": _gantt})
    app[FEED] = feed
    return app
