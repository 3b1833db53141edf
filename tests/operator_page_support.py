"""An operator page driver in a thread of its own, for tests that drive it from a browser (selenium is
blocking): the driver's event loop runs beside the test, which calls into it with `call`."""

from __future__ import annotations

import asyncio
import json
import threading
import urllib.error
import urllib.request
from collections.abc import Callable, Coroutine, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

from common.config.hubs_toml import load_station
from common.model import Value
from hubs.drivers.base import StationContext
from hubs.drivers.operator_page.driver import OperatorPage
from hubs.drivers.operator_page.fake_expander import ButtonOnExpander
from hubs.drivers.operator_page.params import OperatorPageParams
from hubs.drivers.params import convert_params

ROOT = Path(__file__).resolve().parent.parent
T = TypeVar("T")

TOKEN = "watch-token-0123456789"
INSTRUCTIONS = "common.stations.engine_assembly_instructions:INSTRUCTIONS"


class RunningPage:
    def __init__(self, page: OperatorPage, loop: asyncio.AbstractEventLoop) -> None:
        self.page, self.loop = page, loop

    def call(self, work: Callable[[], Coroutine[Any, Any, T]]) -> T:
        return asyncio.run_coroutine_threadsafe(work(), self.loop).result(timeout=30)

    def run(self, action: Callable[[], T]) -> T:
        """`action` in the page's loop (the driver is not thread-safe, as no driver is)."""
        async def inside() -> T:
            return action()
        return self.call(inside)

    @property
    def url(self) -> str:
        assert self.page.server is not None
        return self.page.server.url

    def write(self, **commands: Value) -> None:
        self.call(lambda: self.page.write(commands))

    def observe(self, values: Mapping[str, Value]) -> None:
        self.run(lambda: self.page.observe(values))

    def done(self) -> bool:
        return bool(self.call(self.page.read)["done_m"])

    def post(self, path: str, body: object = None, token: str | None = None) -> tuple[int, dict[str, Any]]:
        data = b"" if body is None else json.dumps(body).encode()
        request = urllib.request.Request(self.url + path, data=data, method="POST",
                                         headers={"Content-Type": "application/json"})
        if token is not None:
            request.add_header("Authorization", f"Bearer {token}")
        try:
            with urllib.request.urlopen(request, timeout=10) as response:
                return response.status, json.loads(response.read())
        except urllib.error.HTTPError as error:
            return error.code, json.loads(error.read())


@contextmanager
def running_page(params: Mapping[str, Any] | None = None, *, expander: ButtonOnExpander | None = None,
                 config_path: Path = ROOT / "hubs.toml") -> Iterator[RunningPage]:
    """The reference station's operator `human` served on a free port of loopback."""
    config, model = load_station(config_path)
    raw = {"host": "127.0.0.1", "port": 0, "instructions": INSTRUCTIONS, "badge_reader": "rfid", "robot": "ur",
           **(params or {})}
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, name="operator-page", daemon=True)
    thread.start()

    async def build() -> OperatorPage:
        page = OperatorPage("human", convert_params(OperatorPageParams, raw),
                            button_bus=expander.open if expander is not None else None)
        page.join_station(StationContext(model, config, "human"))
        await page.connect()
        return page

    page = asyncio.run_coroutine_threadsafe(build(), loop).result(timeout=30)
    try:
        yield RunningPage(page, loop)
    finally:
        asyncio.run_coroutine_threadsafe(page.close(), loop).result(timeout=30)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(10)
        loop.close()
