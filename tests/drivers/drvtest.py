"""Shared helpers for the driver tests: polling with generous functional bounds (never a timing assertion)."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from typing import Any

from hubs.drivers.base import DeviceUnavailable, Driver


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
