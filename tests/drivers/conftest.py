"""Fixtures of the driver tests: drivers connected to their simulated devices, simulators serving."""

from __future__ import annotations

from collections.abc import AsyncIterator
from typing import Any

import pytest

from hubs.drivers.reconnect import LinkedDriver
from tests.drivers.drvtest import Connect, Serve, Server, reconnect_logic


@pytest.fixture
async def serve() -> AsyncIterator[Serve]:
    """Start simulators in this process; each is stopped after the test (after the drivers are closed)."""
    started: list[Server] = []

    async def start(server: Any) -> Any:
        await server.start()
        started.append(server)
        return server

    yield start
    for server in reversed(started):
        await server.stop()


@pytest.fixture
async def connect() -> AsyncIterator[Connect]:
    """Connect drivers to their devices, failing the test if one does not connect in time; each is
    closed after the test."""
    opened: list[LinkedDriver[Any]] = []

    async def connect_driver(driver: Any, timeout: float = 5.0) -> Any:
        opened.append(driver)
        await driver.connect()
        logic = reconnect_logic(driver)
        assert await logic.wait_connected(timeout), f"{logic.name}: no connection in {timeout} s: {logic.last_error}"
        return driver

    yield connect_driver
    for driver in reversed(opened):
        await driver.close()
