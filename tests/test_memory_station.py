"""The hub runtime and the controller service together in this process, over the in-memory bus.

`MemoryStation` runs a hubs.toml's controller (`ControllerService`) and hubs
(`HubRuntime` with emulated drivers) as tasks of the test's event loop, each on its own
`MemoryBus` of one `MemoryHub`, and a watcher bus that reads `{station}/ctl/status` and
the commands as a console would. No process, port or Zenoh session: the same code paths
as a real station above the bus (tests/test_faults.py runs them as real processes).

The fault-test station (a robot, a nutrunner, 4 bolts) runs in about a second; the
reference station is `slow` because building its controller (synthesis, planner
tables) alone takes seconds.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import pytest

from common.bus.memory_bus import MemoryBus, MemoryHub
from common.bus.protocol import Sample, Subscription
from common.config.hubs_toml import load_station
from common.model import Value
from common.wire.ctl import HubGone, StatusMessage
from common.wire.messages import Codec, MessageError
from controller.console.statusview import StatusFollower
from controller.service import ControllerService
from hubs.factory import build_drivers
from hubs.runtime import HubRuntime

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "hubs.toml"
FAULT_STATION = ROOT / "tests" / "fault_station" / "hubs.toml"
WAIT_S = 30.0  # generous bound for a loaded machine; the runs take a few seconds


class LastCommand(NamedTuple):
    values: dict[str, Value]  # a command has every variable known
    seq: int
    controller: str


@dataclass
class Running:
    bus: MemoryBus
    stop: asyncio.Event
    task: asyncio.Task[None]


class MemoryStation:
    """A station's controller and hubs as tasks on one event loop, over one `MemoryHub`."""

    def __init__(self, config_path: Path, db: Path, *, speed: float = 1.0, hold: bool = False) -> None:
        self.config, self.model = load_station(config_path)
        self.keys = self.config.keys
        self.codecs = {r.name: Codec(r) for r in self.model.resources}
        self.db, self.speed, self.hold = db, speed, hold
        self.network = MemoryHub()
        self.running: dict[str, Running] = {}
        self.statuses: list[StatusMessage] = []
        self.commands: list[Sample] = []
        self._watch: list[asyncio.Task[None]] = []
        self.watcher: MemoryBus | None = None

    async def start(self) -> None:
        self.watcher = await MemoryBus(self.network).open()
        statuses = self.watcher.subscribe(self.keys.ctl("status"), coalesce=False, maxlen=None)
        commands = self.watcher.subscribe(self.keys.all_cmd, coalesce=False, maxlen=None)
        self._watch = [asyncio.create_task(self._follow_status(statuses)),
                       asyncio.create_task(self._record(commands, self.commands.append))]
        await self.start_controller()
        for hub in self.config.hubs:
            await self.start_hub(hub)

    async def start_controller(self) -> None:
        bus = await MemoryBus(self.network).open()
        # The planner searches in a thread of this process; its model tables are built before the first
        # request, as the controller's planner process builds them when it starts.
        service = ControllerService(self.config, self.model, bus, db=str(self.db), planner_process=False,
                                    hold=self.hold)
        service.core.planner.prepare()
        stop = asyncio.Event()
        self.running["controller"] = Running(bus, stop, asyncio.create_task(service.run(stop), name="controller"))

    async def start_hub(self, hub: str) -> None:
        settings = self.config.hubs[hub]
        drivers = build_drivers(self.config, hub, self.model, speed=self.speed, seed=1)
        bus = await MemoryBus(self.network).open()
        runtime = HubRuntime(hub=hub, station=self.config.station.name, model=self.model, drivers=drivers,
                             bus=bus, rate_hz=settings.rate_hz, command_timeout_s=settings.command_timeout_s)
        stop = asyncio.Event()
        self.running[hub] = Running(bus, stop, asyncio.create_task(runtime.run(stop), name=hub))

    async def stop(self, name: str) -> None:
        """Stop a process as SIGTERM does: it ends its loop, then its bus closes."""
        running = self.running.pop(name)
        running.stop.set()
        try:
            await asyncio.wait_for(running.task, WAIT_S)
        finally:
            await running.bus.close()

    async def close(self) -> None:
        for name in list(self.running):
            with contextlib.suppress(Exception):
                await self.stop(name)
        for task in self._watch:
            task.cancel()
        await asyncio.gather(*self._watch, return_exceptions=True)
        if self.watcher is not None:
            await self.watcher.close()
        gc.unfreeze()  # the controller froze the collector's view of its model; the next test builds another

    @staticmethod
    async def _record(subscription: Subscription[Sample], record: Callable[[Sample], None]) -> None:
        async for sample in subscription:
            record(sample)

    async def _follow_status(self, subscription: Subscription[Sample]) -> None:
        assert self.watcher is not None
        follower = StatusFollower(self.watcher, self.keys)  # the controller's deltas, merged: full statuses
        async for sample in subscription:
            with contextlib.suppress(MessageError):
                status = await follower.take(sample.payload)
                if status is not None:
                    self.statuses.append(status)

    # what the watcher saw
    def status(self) -> StatusMessage | None:
        return self.statuses[-1] if self.statuses else None

    def current_status(self) -> StatusMessage:
        """The latest status, where the test has seen one already."""
        status = self.status()
        assert status is not None, "no status from the controller yet"
        return status

    def finished_operations(self) -> list[str]:
        status = self.status()
        return [op.name for op in status.operations if op.state == "finished"] if status is not None else []

    def health(self) -> dict[str, tuple[bool, str]]:
        status = self.status()
        return {h.resource: (h.healthy, h.reason) for h in status.health} if status is not None else {}

    def last_commands(self) -> dict[str, LastCommand]:
        """Per commanded resource: the values, seq and controller of the last command the watcher saw."""
        last: dict[str, LastCommand] = {}
        for sample in self.commands:
            resource = self.keys.resource_of(sample.key) or sample.key
            codec = self.codecs[resource]
            command = codec.decode_command(sample.payload)
            last[resource] = LastCommand(codec.values(command), command.seq, command.controller)
        return last

    def all_healthy(self) -> bool:
        health = self.health()
        return bool(health) and all(healthy for healthy, _ in health.values())

    def check(self) -> None:
        """A process that ended on its own is a failure, with its exception."""
        for name, running in self.running.items():
            if running.task.done():
                raise AssertionError(f"{name} ended: {running.task.exception()!r}")

    async def wait_for(self, condition: Callable[[], bool], what: str, timeout: float = WAIT_S) -> None:
        deadline = time.monotonic() + timeout
        while not condition():
            self.check()
            if time.monotonic() > deadline:
                raise AssertionError(f"not within {timeout:.0f} s: {what}; last status: {self.status()}")
            await asyncio.sleep(0.02)


@pytest.fixture
async def station_at(tmp_path: Path) -> AsyncIterator[Callable[..., Awaitable[MemoryStation]]]:
    stations: list[MemoryStation] = []

    async def start(config_path: Path, *, speed: float = 1.0, hold: bool = False) -> MemoryStation:
        station = MemoryStation(config_path, tmp_path / "controller.sqlite", speed=speed, hold=hold)
        stations.append(station)
        await station.start()
        return station

    try:
        yield start
    finally:
        for station in stations:
            await station.close()


async def test_the_controller_and_the_hubs_run_the_station_to_the_end(
        station_at: Callable[..., Awaitable[MemoryStation]]) -> None:
    station = await station_at(FAULT_STATION, speed=5.0)
    await station.wait_for(lambda: (status := station.status()) is not None and status.finished,
                           "every operation finishes")
    status = station.current_status()
    assert {op.state for op in status.operations} == {"finished"}, status.operations
    assert set(station.last_commands()) == {"nr", "ur"}
    assert station.all_healthy(), station.health()


@pytest.mark.slow  # building the reference station's controller (synthesis, planner tables) takes seconds
async def test_the_reference_station_runs_its_first_operations(
        station_at: Callable[..., Awaitable[MemoryStation]]) -> None:
    station = await station_at(REFERENCE, speed=20.0)
    await station.wait_for(lambda: len(station.finished_operations()) >= 3, "three operations finish")
    status = station.current_status()
    assert not any(op.state == "error" for op in status.operations), status.operations
    assert station.all_healthy(), station.health()


async def test_a_stopped_hub_is_unhealthy_and_healthy_again_when_it_is_back(
        station_at: Callable[..., Awaitable[MemoryStation]]) -> None:
    station = await station_at(FAULT_STATION, hold=True)
    await station.wait_for(station.all_healthy, "every resource healthy")
    await station.stop("pi-tool")
    await station.wait_for(lambda: not station.health()["nr"][0], "nr unhealthy")
    reason = station.health()["nr"][1]
    assert "not alive" in reason, reason
    assert station.health()["ur"] == (True, "")  # the other hub's resource is not touched
    assert HubGone(hub="pi-tool") in station.current_status().events
    await station.start_hub("pi-tool")
    await station.wait_for(station.all_healthy, "nr healthy again after the hub's restart")


async def test_garbage_on_a_state_key_is_logged_and_dropped_and_changes_no_output(
        station_at: Callable[..., Awaitable[MemoryStation]], caplog: pytest.LogCaptureFixture) -> None:
    station = await station_at(FAULT_STATION, hold=True)
    await station.wait_for(station.all_healthy, "every resource healthy")
    await station.wait_for(lambda: set(station.last_commands()) == {"nr", "ur"}, "both resources commanded")
    assert station.watcher is not None
    commands_before = station.last_commands()
    statuses_before = len(station.statuses)
    with caplog.at_level(logging.WARNING, logger="statehub.controller"):
        for _ in range(3):
            station.watcher.publish(station.keys.state("nr"), b"\x93garbage")
            await asyncio.sleep(0.05)
        await station.wait_for(lambda: len(station.statuses) > statuses_before + 2, "statuses after the garbage")
    dropped = [r.getMessage() for r in caplog.records if "dropped state" in r.getMessage()]
    assert len(dropped) == 1 and station.keys.state("nr") in dropped[0], dropped  # logged once per key and interval
    # It re-sends the very same commands (no new seq), and nothing became unhealthy.
    assert station.last_commands() == commands_before
    assert station.all_healthy(), station.health()
