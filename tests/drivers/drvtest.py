"""Shared helpers for the driver tests: polling with generous functional bounds (never a timing assertion),
simulators run as processes, and the types of the fixtures in conftest.py (`connect`, `serve`)."""

from __future__ import annotations

import asyncio
import contextlib
import os
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any, Protocol, TypeVar

from hubs.drivers.base import DeviceUnavailable, Driver
from hubs.drivers.modbus_io import ModbusLink
from hubs.drivers.reconnect import LinkedDriver, ReconnectLogic

REPO = Path(__file__).resolve().parents[2]
D = TypeVar("D", bound=LinkedDriver[Any])


class Server(Protocol):
    """A simulator serving in this process (the MiR REST server, the Modbus coupler, the camera tracker)."""

    async def start(self) -> object: ...  # some return the port they listen on

    async def stop(self) -> None: ...


S = TypeVar("S", bound=Server)


class Connect(Protocol):
    """The `connect` fixture: `await connect(driver)` returns the driver connected to its device."""

    def __call__(self, driver: D, timeout: float = 5.0) -> Awaitable[D]: ...


class Serve(Protocol):
    """The `serve` fixture: `await serve(server)` returns the simulator serving."""

    def __call__(self, server: S) -> Awaitable[S]: ...


def reconnect_logic(driver: LinkedDriver[Any]) -> ReconnectLogic:
    """The driver's connection state (a Modbus driver's link wraps it)."""
    link = driver.link
    return link.reconnect if isinstance(link, ModbusLink) else link


@contextlib.asynccontextmanager
async def simulator_process(module: str, *args: str,
                            stdin: bool = False) -> AsyncIterator[tuple[subprocess.Popen[str], str]]:
    """`python -m MODULE ARGS`, a simulator on its own as `hubctl up --mode sim` runs it: yields the process
    and the first line it prints (where it serves); kills it at the end."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-m", module, *args], stdin=subprocess.PIPE if stdin else None,
                            stdout=subprocess.PIPE, text=True, env=env, cwd=REPO)
    try:
        assert proc.stdout is not None
        line = await asyncio.wait_for(asyncio.to_thread(proc.stdout.readline), 15)
        yield proc, line.strip()
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()


async def eventually(probe: Callable[[], Any], timeout: float = 5.0, interval: float = 0.01) -> Any:
    """Wait until ``probe()`` (sync or async) returns a truthy value; return it. Fails after ``timeout``."""
    deadline = time.monotonic() + timeout
    last: Any = None
    while True:
        try:
            last = probe()
            if isinstance(last, Awaitable):
                last = await last
            if last:
                return last
        except DeviceUnavailable as exc:
            last = exc
        if time.monotonic() > deadline:
            raise AssertionError(f"condition not reached within {timeout} s; last value: {last!r}")
        await asyncio.sleep(interval)


async def read_until(driver: Driver, timeout: float = 5.0, **expected: Any) -> dict[str, Any]:
    """Read the driver until every expected variable has its value; return that reading."""

    async def probe() -> dict[str, Any] | None:
        values = dict(await driver.read())
        return values if all(values.get(k) == v for k, v in expected.items()) else None

    result: dict[str, Any] = await eventually(probe, timeout)
    return result
