"""systemd's notify protocol (common/plumbing/sdnotify.py): READY=1 once, WATCHDOG=1 from the hub's loop, nothing
without $NOTIFY_SOCKET. A datagram socket of the test stands in for systemd."""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from common.bus.memory_bus import MemoryBus, MemoryHub
from common.config.hubs_toml import load_station
from common.plumbing.sdnotify import Notifier
from hubs.factory import build_drivers
from hubs.runtime import HubRuntime
from tests.test_memory_station import FAULT_STATION


@pytest.fixture
def systemd(tmp_path: Path) -> Iterator[socket.socket]:
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    listener.bind(str(tmp_path / "notify"))
    listener.setblocking(False)
    try:
        yield listener
    finally:
        listener.close()


def received(listener: socket.socket) -> list[str]:
    messages = []
    while True:
        try:
            messages.append(listener.recv(4096).decode())
        except BlockingIOError:
            return messages


def test_without_notify_socket_nothing_is_sent(systemd: socket.socket) -> None:
    notifier = Notifier({})
    notifier.ready()
    notifier.alive()
    assert notifier.period is None and received(systemd) == []


def test_ready_once_and_the_watchdog_at_half_its_period(systemd: socket.socket) -> None:
    notifier = Notifier({"NOTIFY_SOCKET": systemd.getsockname(), "WATCHDOG_USEC": "10000000"})
    assert notifier.period == 5.0
    notifier.ready()
    for _ in range(100):  # a loop at 50 Hz for 2 s: one feed, not a hundred
        notifier.alive()
    assert received(systemd) == ["READY=1", "WATCHDOG=1"]
    notifier.close()


def test_a_watchdog_meant_for_another_process_is_not_fed(systemd: socket.socket) -> None:
    notifier = Notifier({"NOTIFY_SOCKET": systemd.getsockname(), "WATCHDOG_USEC": "1000", "WATCHDOG_PID": "1"})
    notifier.alive()
    assert received(systemd) == []


async def test_the_hub_says_ready_and_feeds_the_watchdog_from_its_loop(
        systemd: socket.socket, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NOTIFY_SOCKET", systemd.getsockname())
    monkeypatch.setenv("WATCHDOG_USEC", "100000")  # fed every 50 ms
    config, model = load_station(FAULT_STATION)
    bus = await MemoryBus(MemoryHub()).open()
    runtime = HubRuntime(hub="pi-tool", station=config.station.name, model=model,
                         drivers=build_drivers(config, "pi-tool", model, seed=1), bus=bus, rate_hz=50,
                         command_timeout_s=1.0)
    stop = asyncio.Event()
    task = asyncio.create_task(runtime.run(stop))
    messages: list[str] = []
    for _ in range(200):
        await asyncio.sleep(0.02)
        messages += received(systemd)
        if messages.count("WATCHDOG=1") >= 3:
            break
    stop.set()
    await task
    await bus.close()
    assert messages[0] == "READY=1" and messages.count("READY=1") == 1
    assert messages.count("WATCHDOG=1") >= 3, messages
