"""The hub contract, against a real hub process (`python -m hubs`) over Zenoh on loopback.

The test process plays the controller: it listens where the hub connects, sends
commands, and reads states, mirrors, liveliness and the self-test report.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import msgspec
import pytest

from common.bus.protocol import Bus, Reply
from common.bus.zenoh_bus import ZenohBus
from common.bus.zenoh_config import zenoh_config
from common.config.hubs_toml import load_station
from common.plumbing.lifecycle import free_port
from common.wire.holder_token import declare_holder
from common.wire.keys import station_keys
from common.wire.messages import SCHEMA, Codec, HubStatus, decode
from common.wire.selftest_report import SelftestMessage
from tests.hub_process import HubProcess

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "hubs.toml"


class HubUnderTest:
    def __init__(self, bus: Bus, hub: HubProcess, station: str) -> None:
        self.bus, self.process = bus, hub
        self.keys = station_keys(station)
        _, model = load_station(CONFIG)
        self.codec = Codec(model.resource_by_name["nr"])
        self.states = bus.subscribe(self.keys.state("nr"), coalesce=False)
        # Any: a resource's state struct is generated from its model at run time; its fields have no static type.
        self.last: Any = None

    async def state_where(self, predicate: Callable[[Any], bool], timeout: float = 5.0) -> Any:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                sample = await asyncio.wait_for(self.states.get(), max(0.01, deadline - time.monotonic()))
            except TimeoutError:
                break
            self.last = self.codec.decode_state(sample.payload)
            if predicate(self.last):
                return self.last
        raise AssertionError(f"no matching state within {timeout} s; last: {self.last}\nhub log:\n"
                             f"{self.process.log.read_text()[-3000:]}")

    def command(self, seq: int, run_c: bool) -> None:
        message = self.codec.command({"run_c": run_c}, seq=seq, controller="test-controller")
        self.bus.publish(self.keys.cmd("nr"), self.codec.encode_command(message))


@pytest.fixture
async def hub(hub_process: Callable[..., HubProcess]) -> AsyncIterator[HubUnderTest]:
    port = free_port()
    config, _ = load_station(CONFIG)
    listen = [f"tcp/127.0.0.1:{port}"]
    async with ZenohBus(zenoh_config("peer", listen=listen, lease_ms=config.network.lease_ms)) as bus:
        declare_holder(bus, config.keys, "test-controller")  # the hub applies the holder's commands only
        alive = bus.watch_liveliness(config.keys.alive("pi-tool"))
        process = hub_process(CONFIG, "pi-tool", port, "--speed", "4")
        event = await asyncio.wait_for(alive.get(), 15)
        assert event.alive
        under = HubUnderTest(bus, process, config.station.name)
        # The hub declares its liveliness before its command subscribers, and those before it publishes: a
        # command sent before its first state is seen here can find no subscriber yet and is lost (a fresh
        # clone's suite under load lost one). A controller resends; these tests send each command once.
        await under.state_where(lambda s: True, timeout=15)
        yield under


async def test_commands_are_applied_mirrored_and_drive_the_device(hub: HubUnderTest) -> None:
    first = await hub.state_where(lambda s: True)
    assert first.status == HubStatus.NO_COMMAND and first.mirror is None
    hub.command(1, True)
    applied = await hub.state_where(lambda s: s.mirror is not None and s.mirror.seq == 1)
    assert applied.status == HubStatus.OK and applied.mirror.run_c is True
    # The emulated nutrunner does what the model's effects say: it runs, then reaches torque.
    await hub.state_where(lambda s: s.run_m is True)
    await hub.state_where(lambda s: s.tqr_m is True or s.fail_m is True)
    # Keep sending, as the controller does; an older command from the same controller is ignored.
    hub.command(2, False)
    await hub.state_where(lambda s: s.mirror is not None and s.mirror.seq == 2)
    hub.command(1, True)
    await asyncio.sleep(0.3)
    latest = await hub.state_where(lambda s: s.mirror is not None)
    assert latest.mirror.seq == 2 and latest.mirror.run_c is False


async def test_out_of_domain_and_garbage_commands_change_nothing(hub: HubUnderTest) -> None:
    hub.command(5, False)
    await hub.state_where(lambda s: s.mirror is not None and s.mirror.seq == 5)
    raw = msgspec.msgpack.encode({"schema": SCHEMA, "model_hash": hub.codec.model_hash, "run_c": 3, "seq": 6,
                                  "controller": "test-controller", "time": time.time()})
    hub.bus.publish(hub.keys.cmd("nr"), raw)
    rejected = await hub.state_where(lambda s: s.status == HubStatus.REJECTED)
    assert "run_c" in rejected.detail and rejected.mirror.seq == 5 and rejected.mirror.run_c is False
    for garbage in (b"", b"\x00\xff", raw[:7], msgspec.msgpack.encode([1, 2, 3])):
        hub.bus.publish(hub.keys.cmd("nr"), garbage)
    await asyncio.sleep(0.3)
    assert hub.process.alive()
    after = await hub.state_where(lambda s: True)
    assert after.mirror.seq == 5 and after.run_m is False


async def test_another_controllers_command_changes_nothing_and_the_holders_refused_one_is_reported(
        hub: HubUnderTest) -> None:
    hub.command(5, False)
    await hub.state_where(lambda s: s.mirror is not None and s.mirror.seq == 5)
    intruder = hub.codec.command({"run_c": True}, seq=99, controller="intruder")
    hub.bus.publish(hub.keys.cmd("nr"), hub.codec.encode_command(intruder))
    await asyncio.sleep(0.3)
    # Not the holder's: dropped before it is decoded; no output, mirror or status of it.
    after = await hub.state_where(lambda s: True)
    assert after.status == HubStatus.OK and after.mirror.seq == 5 and after.mirror.run_c is False
    assert after.run_m is False
    assert "ignored command on engine_assembly/res/nr/cmd from intruder (epoch 0): not the station's holder " \
           "(held by controller test-controller" in hub.process.log.read_text()
    # The holder's out-of-domain command: refused and said so, naming it; nothing of it applied.
    raw = msgspec.msgpack.encode({"schema": SCHEMA, "model_hash": hub.codec.model_hash, "run_c": 3, "seq": 99,
                                  "controller": "test-controller", "time": time.time()})
    hub.bus.publish(hub.keys.cmd("nr"), raw)
    rejected = await hub.state_where(lambda s: s.status == HubStatus.REJECTED)
    assert "seq 99 from test-controller" in rejected.detail and "run_c" in rejected.detail
    assert rejected.mirror.seq == 5 and rejected.mirror.run_c is False and rejected.run_m is False
    # Our controller's next re-send is applied again and clears the status at once.
    hub.command(5, False)
    cleared = await hub.state_where(lambda s: s.status != HubStatus.REJECTED)
    assert cleared.status == HubStatus.OK and cleared.detail == "" and cleared.mirror.seq == 5


async def test_silence_drives_the_safe_state(hub: HubUnderTest) -> None:
    hub.command(1, True)
    await hub.state_where(lambda s: s.run_m is True)
    # No more commands: after the command timeout the hub drives run_c false and says so.
    safe = await hub.state_where(lambda s: s.status == HubStatus.SAFE_STATE, timeout=4)
    assert "no command within" in safe.detail
    # The device follows its safe output: the emulated nutrunner resets.
    await hub.state_where(lambda s: s.run_m is False, timeout=4)
    hub.command(2, False)
    resumed = await hub.state_where(lambda s: s.status == HubStatus.OK)
    assert resumed.mirror.seq == 2


async def test_selftest_report_and_liveliness(hub: HubUnderTest) -> None:
    deadline = time.monotonic() + 10
    replies: list[Reply] = []
    while time.monotonic() < deadline and not replies:
        replies = [r for r in await hub.bus.get(hub.keys.selftest("pi-tool"), timeout=1.0) if r.ok]
        await asyncio.sleep(0.2)
    assert replies, "no self-test report"
    report = decode(replies[0].payload, SelftestMessage)
    assert report.ok and {d.resource for d in report.devices} == {"nr", "lift"}
    gone = hub.bus.watch_liveliness(hub.keys.alive("pi-tool"), history=False)
    hub.process.kill()
    event = await asyncio.wait_for(gone.get(), 5)
    assert event.alive is False
