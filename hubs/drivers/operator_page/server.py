"""The operator's page over HTTP (aiohttp): the static page, its updates as server-sent events, and the
few requests it may make. Read-only but for this operator's button and the call for the supervisor.

| method, path                | what                                                                  |
|-----------------------------|-----------------------------------------------------------------------|
| GET  /                      | the page (static/index.html)                                          |
| GET  /static/NAME           | its CSS and JavaScript                                                |
| GET  /pictures/TASK         | the picture of a task's instruction                                   |
| GET  /api/view              | what the page shows now (JSON, `PageView`)                            |
| GET  /events                | the same at every change, as server-sent events                       |
| POST /api/confirm           | press the Confirm button; body `{"task": T}` optional (must stand)    |
| POST /api/call-supervisor   | call the supervisor                                                   |

When the device has `tokens`, both POSTs need `Authorization: Bearer TOKEN` (403 otherwise, nothing
changes). A refused press answers 409 with the reason, in the console's words."""

from __future__ import annotations

import asyncio
import contextlib
import enum
import json
import logging
import ssl
from pathlib import Path
from typing import Protocol

import msgspec
from aiohttp import web

from .tokens import DeviceTokens
from .view import PageView

log = logging.getLogger(__name__)

STATIC = Path(__file__).with_name("static")
KEEPALIVE_S = 10.0  # a comment line on an idle event stream, so that proxies and the browser keep it open
SHUTDOWN_S = 1.0


class Refusal(enum.StrEnum):
    """Why a press changed nothing, and the HTTP status that says it."""

    UNKNOWN_TASK = "unknown_task"  # the request names no task of this operator: 400
    NOT_STANDING = "not_standing"  # it names a task that is not the instruction standing: 409
    CANNOT_CONFIRM = "cannot_confirm"  # no instruction, already confirmed, or the condition does not hold: 409


HTTP_STATUS = {Refusal.UNKNOWN_TASK: 400, Refusal.NOT_STANDING: 409, Refusal.CANNOT_CONFIRM: 409}


class PressOutcome(msgspec.Struct, frozen=True):
    accepted: bool
    reason: str = ""
    refusal: Refusal | None = None


class Page(Protocol):
    """What the server serves: the driver behind it."""

    def view(self) -> PageView: ...
    def press(self, device: str, task: str | None) -> PressOutcome: ...
    def call_supervisor(self, device: str) -> None: ...
    def picture(self, task: str) -> Path | None: ...
    async def changed(self, timeout: float) -> None: ...


class PageServer:
    def __init__(self, page: Page, tokens: DeviceTokens, host: str, port: int,
                 tls: ssl.SSLContext | None = None) -> None:
        self.page, self.tokens, self.host, self.port, self.tls = page, tokens, host, port, tls
        self._runner: web.AppRunner | None = None
        self._closing = asyncio.Event()
        self.bound: tuple[str, int] | None = None  # the address it listens on once started

    @property
    def url(self) -> str:
        host, port = self.bound or (self.host, self.port)
        return f"{'https' if self.tls else 'http'}://{host}:{port}/"

    def app(self) -> web.Application:
        app = web.Application()
        app.add_routes([
            web.get("/", self._index),
            web.static("/static", STATIC),
            web.get("/pictures/{task}", self._picture),
            web.get("/api/view", self._view),
            web.get("/events", self._events),
            web.post("/api/confirm", self._confirm),
            web.post("/api/call-supervisor", self._call),
        ])
        return app

    async def start(self) -> None:
        self._closing.clear()
        self._runner = web.AppRunner(self.app(), access_log=None, shutdown_timeout=SHUTDOWN_S)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.host, self.port, ssl_context=self.tls)
        await site.start()
        server = site._server  # the port actually bound (0 in tests: a free one)
        sockets = getattr(server, "sockets", None) or []
        self.bound = sockets[0].getsockname()[:2] if sockets else (self.host, self.port)
        log.info("operator page on %s", self.url)

    async def stop(self) -> None:
        self._closing.set()  # ends the event streams, which would otherwise hold the shutdown
        runner, self._runner = self._runner, None
        if runner is not None:
            await runner.cleanup()

    # --- reads -----------------------------------------------------------------------------------
    async def _index(self, _request: web.Request) -> web.FileResponse:
        return web.FileResponse(STATIC / "index.html")

    async def _picture(self, request: web.Request) -> web.StreamResponse:
        path = self.page.picture(request.match_info["task"])
        if path is None or not path.is_file():
            raise web.HTTPNotFound(text="no picture for this task")
        return web.FileResponse(path)

    async def _view(self, _request: web.Request) -> web.Response:
        return web.Response(body=msgspec.json.encode(self.page.view()), content_type="application/json")

    async def _events(self, request: web.Request) -> web.StreamResponse:
        response = web.StreamResponse(headers={"Content-Type": "text/event-stream", "Cache-Control": "no-cache"})
        await response.prepare(request)
        sent = b""
        with contextlib.suppress(ConnectionResetError, asyncio.CancelledError):
            while not self._closing.is_set():
                data = msgspec.json.encode(self.page.view())
                await response.write(b"data: " + data + b"\n\n" if data != sent else b": idle\n\n")
                sent = data
                waiting = asyncio.ensure_future(self.page.changed(KEEPALIVE_S))
                closing = asyncio.ensure_future(self._closing.wait())
                try:
                    await asyncio.wait((waiting, closing), return_when=asyncio.FIRST_COMPLETED)
                finally:
                    waiting.cancel()
                    closing.cancel()
        return response

    # --- the two things the page may change ---------------------------------------------------------
    def _device(self, request: web.Request) -> str:
        """The device pressing (its token's name); 403 when the token is wrong or missing."""
        if not self.tokens.required:
            return "page"
        device = self.tokens.device_of(DeviceTokens.from_header(request.headers.get("Authorization", "")))
        if device is None:
            raise web.HTTPForbidden(text=json.dumps({"accepted": False, "reason": "wrong or missing device token"}),
                                    content_type="application/json")
        return device

    async def _confirm(self, request: web.Request) -> web.Response:
        device = self._device(request)
        task = None
        if request.can_read_body:
            try:
                body = await request.json()
            except json.JSONDecodeError:
                return _answer(PressOutcome(False, "the body is not JSON", Refusal.UNKNOWN_TASK), 400)
            if not isinstance(body, dict) or not isinstance(body.get("task", ""), str):
                return _answer(PressOutcome(False, 'expected {"task": "TASK"} or no body', Refusal.UNKNOWN_TASK), 400)
            task = body.get("task") or None
        outcome = self.page.press(device, task)
        return _answer(outcome, 200 if outcome.refusal is None else HTTP_STATUS[outcome.refusal])

    async def _call(self, request: web.Request) -> web.Response:
        self.page.call_supervisor(self._device(request))
        return _answer(PressOutcome(True, "the supervisor is called"), 200)


def _answer(outcome: PressOutcome, status: int) -> web.Response:
    return web.Response(body=msgspec.json.encode(outcome), status=status, content_type="application/json")
