"""The hub runtime and the driver contract, in one process on the in-memory bus (common.bus.memory_bus).

* the safe state: the hub has the driver enter it at start and when commands stop, mirrors
  exactly the command values the driver says it applied, writes nothing else, and applies
  and mirrors the first command that follows like any other;
* declared capabilities: the hub subscribes to other resources' variables only for a driver
  that declares `Inputs`, and hands their values only to a driver that `Observes`.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Mapping
from typing import Any

from common.bus.memory_bus import MemoryBus, MemoryHub
from common.bus.protocol import Sample, Subscription
from common.model import Model, Resource, Value, command, measured
from common.wire.holder_token import declare_holder
from common.wire.keys import station_keys
from common.wire.messages import Codec, HubStatus
from hubs.drivers.base import DeviceUnavailable, Driver, Inputs, Observes, SelftestReport
from hubs.runtime import HubRuntime

STATION = "demo"


def two_tools() -> Model:
    return Model("demo", (
        Resource("nr", (command("nr.run_c"), measured("nr.run_m")), device_type="nutrunner"),
        Resource("rsp", (command("rsp.lock_c"), measured("rsp.locked_m")), device_type="rsp"),
    ))


class RecordingBus(MemoryBus):
    """The in-memory bus, keeping what the hub published and which keys it subscribed to."""

    def __init__(self) -> None:
        super().__init__(MemoryHub())
        self.published: list[Sample] = []
        self.subscribed: list[str] = []

    def publish(self, key: str, payload: bytes, *, block: bool = False) -> None:
        self.published.append(Sample(key, payload))
        super().publish(key, payload, block=block)

    def subscribe(self, key: str, **options: Any) -> Subscription[Sample]:
        self.subscribed.append(key)
        return super().subscribe(key, **options)


class RecordingDriver(Driver):
    """A device whose safe state is `safe`; it records every write."""

    def __init__(self, resource: str, command_name: str, measured_name: str, safe: Mapping[str, Value]) -> None:
        self.resource = resource
        self.command_name, self.measured_name = command_name, measured_name
        self.safe = dict(safe)
        self.writes: list[dict[str, Value]] = []
        self.safe_states = 0
        self.output: Value = False

    async def connect(self) -> None:
        return None

    async def close(self) -> None:
        return None

    @property
    def connected(self) -> bool:
        return True

    async def read(self) -> Mapping[str, Value]:
        return {self.measured_name: self.output}

    async def write(self, commands: Mapping[str, Value]) -> None:
        self.writes.append(dict(commands))
        self.output = commands[self.command_name]

    async def enter_safe_state(self) -> Mapping[str, Value]:
        self.safe_states += 1
        self.output = self.safe.get(self.command_name, self.output)
        return dict(self.safe)

    async def selftest(self) -> SelftestReport:
        return SelftestReport(self.resource)


class Hub:
    def __init__(self, drivers: Mapping[str, Driver], command_timeout_s: float = 0.3) -> None:
        self.model = two_tools()
        self.bus = RecordingBus()
        self.keys = station_keys(STATION)
        self.codecs = {r.name: Codec(r) for r in self.model.resources}
        self.runtime = HubRuntime(hub="h", station=STATION, model=self.model, drivers=drivers,
                                  bus=self.bus, rate_hz=50, command_timeout_s=command_timeout_s)
        self.stop = asyncio.Event()
        self.task: asyncio.Task[None] | None = None

    async def __aenter__(self) -> Hub:
        await self.bus.open()
        self.holder = declare_holder(self.bus, self.keys, "test")  # the hub applies the holder's commands only
        self.task = asyncio.create_task(self.runtime.run(self.stop))
        for resource in self.runtime.slots:  # serving: a command sent from now on is received
            await self.state_where(resource, lambda _state: True)
        return self

    async def __aexit__(self, *_exc: object) -> None:
        self.stop.set()
        assert self.task is not None
        await asyncio.wait_for(self.task, 5)
        await self.bus.close()

    def command(self, resource: str, seq: int, **values: Value) -> None:
        codec = self.codecs[resource]
        message = codec.command(values, seq=seq, controller="test")
        self.bus.publish(self.keys.cmd(resource), codec.encode_command(message))

    async def state_where(self, resource: str, predicate: Callable[[Any], bool], timeout: float = 5.0) -> Any:
        """The first state of `resource` published from now on that satisfies `predicate`."""
        seen = len(self.bus.published)
        key, codec = self.keys.state(resource), self.codecs[resource]
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for sample in self.bus.published[seen:]:
                if sample.key == key and predicate(state := codec.decode_state(sample.payload)):
                    return state
            seen = len(self.bus.published)
            await asyncio.sleep(0.01)
        raise AssertionError(f"no state of {resource} as expected within {timeout} s")


async def test_the_hub_mirrors_what_the_safe_state_applied_and_applies_the_next_command() -> None:
    nutrunner = RecordingDriver("nr", "run_c", "run_m", {"run_c": False})
    changer = RecordingDriver("rsp", "lock_c", "locked_m", {})  # a tool changer never drops its tool
    async with Hub({"nr": nutrunner, "rsp": changer}) as hub:
        start = await hub.state_where("nr", lambda s: True)
        assert start.status == HubStatus.NO_COMMAND and start.mirror is None
        assert nutrunner.safe_states == 1 and nutrunner.writes == []
        assert changer.safe_states == 1 and changer.writes == []  # a hub start writes nothing

        hub.command("nr", 1, run_c=True)
        hub.command("rsp", 1, lock_c=True)
        applied = await hub.state_where("nr", lambda s: s.mirror is not None and s.run_m is True)
        assert applied.mirror.run_c is True and applied.mirror.seq == 1

        # Silence: the driver enters its safe state; the mirror shows what it applied, nothing is written.
        safe = await hub.state_where("nr", lambda s: s.status == HubStatus.SAFE_STATE)
        assert safe.mirror.run_c is False and safe.mirror.seq == 1 and safe.mirror.controller == "test"
        held = await hub.state_where("rsp", lambda s: s.status == HubStatus.SAFE_STATE)
        assert held.mirror.lock_c is True and held.locked_m is True  # left out: keeps its value
        assert nutrunner.writes == [{"run_c": True}] and changer.writes == [{"lock_c": True}]

        # The first command after the safe state, at once: applied and mirrored like any other.
        hub.command("nr", 2, run_c=True)
        resumed = await hub.state_where("nr", lambda s: s.mirror.seq == 2 and s.run_m is True)
        assert resumed.status == HubStatus.OK and resumed.mirror.run_c is True
        assert nutrunner.writes == [{"run_c": True}, {"run_c": True}]


class Unplugged(RecordingDriver):
    """Takes its first command, then its device is gone: every later write raises DeviceUnavailable."""

    async def write(self, commands: Mapping[str, Value]) -> None:
        if self.writes:
            raise DeviceUnavailable(f"{self.resource}: unplugged")
        await super().write(commands)


async def _keep_commanding(hub: Hub, resource: str, seconds: float, **values: Value) -> None:
    """The controller's re-sending, every 0.05 s (the hub's command timeout in these tests is 0.3 s)."""
    seq, until = 100, time.monotonic() + seconds
    while time.monotonic() < until:
        seq += 1
        hub.command(resource, seq, **values)
        await asyncio.sleep(0.05)


async def test_commands_the_device_cannot_take_still_keep_the_hub_out_of_its_safe_state() -> None:
    """The command timeout is about a silent controller: commands that arrive while the device is gone
    are not applied (device_lost), but they are no silence."""
    nutrunner = Unplugged("nr", "run_c", "run_m", {"run_c": False})
    async with Hub({"nr": nutrunner}) as hub:
        hub.command("nr", 1, run_c=True)
        await hub.state_where("nr", lambda s: s.status == HubStatus.OK)
        await _keep_commanding(hub, "nr", 1.0, run_c=True)
        states = [hub.codecs["nr"].decode_state(p.payload) for p in hub.bus.published if p.key == hub.keys.state("nr")]
        assert HubStatus.DEVICE_LOST in {s.status for s in states}
        assert HubStatus.SAFE_STATE not in {s.status for s in states}
        assert nutrunner.safe_states == 1  # the hub's start only


class Slow(RecordingDriver):
    """Its second write takes 0.6 s (twice the hub's command timeout in these tests)."""

    async def write(self, commands: Mapping[str, Value]) -> None:
        if len(self.writes) == 1:
            await asyncio.sleep(0.6)
        await super().write(commands)


async def test_a_write_that_takes_its_time_is_not_the_controllers_silence() -> None:
    """Newer commands wait behind a slow write; a safe state driven meanwhile would undo the write."""
    nutrunner = Slow("nr", "run_c", "run_m", {"run_c": False})
    async with Hub({"nr": nutrunner}) as hub:
        hub.command("nr", 1, run_c=True)
        await hub.state_where("nr", lambda s: s.status == HubStatus.OK)
        await _keep_commanding(hub, "nr", 1.2, run_c=False)
        assert nutrunner.safe_states == 1  # the hub's start only
        assert nutrunner.writes[:2] == [{"run_c": True}, {"run_c": False}]


async def test_a_time_the_hub_did_not_run_is_not_the_controllers_silence() -> None:
    """A starved hub process wakes late, the commands that arrived meanwhile still queued behind that
    wake-up: the gap is not counted toward the command timeout. Real silence still is."""
    nutrunner = RecordingDriver("nr", "run_c", "run_m", {"run_c": False})
    async with Hub({"nr": nutrunner}) as hub:
        hub.command("nr", 1, run_c=True)
        await hub.state_where("nr", lambda s: s.status == HubStatus.OK)
        commanding = asyncio.create_task(_keep_commanding(hub, "nr", 1.0, run_c=True))
        await asyncio.sleep(0.2)
        time.sleep(0.6)  # the whole loop stalls (blocked here), longer than the command timeout
        await commanding
        assert nutrunner.safe_states == 1, "the hub's own stall was taken for the controller's silence"
        await hub.state_where("nr", lambda s: s.status == HubStatus.SAFE_STATE)  # silence from here on
        assert nutrunner.safe_states == 2


class Uninterested(RecordingDriver):
    """No Inputs, no Observes: asking it for either is a contract violation."""

    @property
    def inputs(self) -> tuple[str, ...]:
        raise AssertionError("the runtime asked a driver without Inputs for its inputs")

    def observe(self, values: Mapping[str, Value], published_at: float | None = None) -> None:
        raise AssertionError("the runtime handed values to a driver that does not observe")


class Follower(RecordingDriver, Inputs, Observes):
    """Depends on the tool changer's lock."""

    def __init__(self, *args: Any) -> None:
        super().__init__(*args)
        self.observed: dict[str, Value] = {}
        self.published_at: list[float | None] = []

    @property
    def inputs(self) -> tuple[str, ...]:
        return ("rsp.locked_m",)

    def observe(self, values: Mapping[str, Value], published_at: float | None = None) -> None:
        self.observed.update(values)
        self.published_at.append(published_at)


async def test_a_driver_without_inputs_is_never_asked_for_them() -> None:
    alone = Uninterested("nr", "run_c", "run_m", {"run_c": False})
    async with Hub({"nr": alone}) as hub:
        hub.command("nr", 1, run_c=True)
        await hub.state_where("nr", lambda s: s.mirror is not None and s.mirror.seq == 1)
        hub.bus.publish(hub.keys.state("rsp"), hub.codecs["rsp"].encode_state(hub.codecs["rsp"].state(
            {"locked_m": True}, status=HubStatus.OK, seq=1, hub="other")))
        await hub.state_where("nr", lambda s: True)
    assert hub.bus.subscribed == [hub.keys.cmd("nr")]  # nothing of other resources


async def test_a_driver_that_declares_inputs_observes_them() -> None:
    follower = Follower("nr", "run_c", "run_m", {"run_c": False})
    async with Hub({"nr": follower}) as hub:
        assert hub.keys.state("rsp") in hub.bus.subscribed
        state = hub.codecs["rsp"].state({"locked_m": True}, status=HubStatus.OK, seq=1, hub="other", time=1234.5)
        hub.bus.publish(hub.keys.state("rsp"), hub.codecs["rsp"].encode_state(state))
        deadline = time.monotonic() + 5
        while not follower.observed and time.monotonic() < deadline:
            await asyncio.sleep(0.01)
    assert follower.observed == {"rsp.locked_m": True}
    assert follower.published_at == [1234.5]  # when the other hub published it, for causal emulation


class Sloppy(RecordingDriver):
    async def enter_safe_state(self) -> Mapping[str, Value]:
        self.output = False
        return {"run_c": "off"}  # run_c is a bool


async def test_a_safe_state_outside_the_domain_is_an_error_not_a_mirror() -> None:
    sloppy = Sloppy("nr", "run_c", "run_m", {})
    async with Hub({"nr": sloppy}) as hub:
        hub.command("nr", 1, run_c=True)
        await hub.state_where("nr", lambda s: s.mirror is not None and s.mirror.seq == 1)
        failed = await hub.state_where("nr", lambda s: s.status == HubStatus.ERROR)
        assert "safe state" in failed.detail and "outside its domain" in failed.detail
        assert failed.mirror.run_c is True  # the last command, not the driver's slip
        hub.command("nr", 2, run_c=True)
        assert (await hub.state_where("nr", lambda s: s.mirror.seq == 2)).status == HubStatus.OK


class Buggy(RecordingDriver):
    """A driver whose read has a bug until `fixed`."""

    fixed = False

    async def read(self) -> Mapping[str, Value]:
        if not self.fixed:
            raise KeyError("run_m")
        return await super().read()


async def test_a_driver_bug_in_read_is_an_error_status_and_the_hub_keeps_serving() -> None:
    buggy = Buggy("nr", "run_c", "run_m", {"run_c": False})
    healthy = RecordingDriver("rsp", "lock_c", "locked_m", {})
    async with Hub({"nr": buggy, "rsp": healthy}) as hub:
        failed = await hub.state_where("nr", lambda s: s.status == HubStatus.ERROR)
        assert "driver failed to read: KeyError" in failed.detail and failed.run_m is None
        hub.command("rsp", 1, lock_c=True)  # the other device is still served
        assert (await hub.state_where("rsp", lambda s: s.mirror is not None and s.locked_m is True)).status \
            == HubStatus.OK
        buggy.fixed = True
        recovered = await hub.state_where("nr", lambda s: s.status != HubStatus.ERROR)
        assert recovered.run_m is False
