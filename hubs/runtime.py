"""The generic stateless hub: commands in, outputs written, inputs read, state and mirror out.

A hub serves the resources of one ECU. For each one it applies the newest valid
command of the station's holder (hubs/authority.py) and mirrors it, publishes the
measured state at its rate and at once when a command is applied, rejects commands
outside the model's domains (and says so in its status), has the driver enter its safe
state when no command arrived within the command timeout (and mirrors the command values
the driver says it applied), and reports a device that does not answer. It keeps no
control state: a restarted hub starts in the safe state and takes the next command the
controller re-sends. It never knows whether a driver is emulated, simulated or real; a
driver that needs other resources' values declares it (`Inputs`, `Observes`). On
SIGTERM, or when one of its tasks crashes, every driver enters its safe state before
the hub exits (hubs/shutdown.py).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from common.bus.protocol import Bus, Request
from common.model import Kind, Model, Value
from common.plumbing.sdnotify import Notifier
from common.plumbing.tasks import cancel_and_wait
from common.wire.ctl import StateSnapshot
from common.wire.keys import station_keys
from common.wire.messages import (
    Codec,
    CommandMessage,
    DomainError,
    HubStatus,
    MessageError,
    ModelMismatch,
    StateMessage,
    decode,
    encode,
)

from .authority import Authority
from .drivers.base import CallsSupervisor, DeviceUnavailable, Driver, Inputs, Observes, SelftestReport
from .selftest import SelftestMessage, report_message
from .shutdown import close_drivers, safe_state_on_exit, wait_for_stop_or_crash

log = logging.getLogger("statehub.hub")

TASKS_END_S = 2.0  # for the hub's tasks to end once cancelled, before the safe state is driven regardless
DRIVER_CLOSE_S = 2.0  # for the drivers to close their connections on exit


@dataclass
class ResourceSlot:
    name: str
    driver: Driver
    codec: Codec
    mirror: CommandMessage | None = None
    last_command_at: float | None = None
    status: HubStatus = HubStatus.NO_COMMAND  # what became of the commands
    detail: str = ""
    device_problem: str | None = None  # set while the device does not answer
    driver_fault: str | None = None  # set while the driver's read fails with a bug, not a lost device
    seq: int = 0
    in_safe_state: bool = False
    applying: bool = False  # a command's write is under way: the controller is not silent
    measured: Mapping[str, Value | None] = field(default_factory=dict)


class HubRuntime:
    def __init__(self, *, hub: str, station: str, model: Model, drivers: Mapping[str, Driver], bus: Bus,
                 rate_hz: float = 50.0, command_timeout_s: float = 1.0) -> None:
        self.hub = hub
        self.model = model
        self.bus = bus
        self.keys = station_keys(station)
        self.period = 1.0 / rate_hz
        self.command_timeout = command_timeout_s
        self.slots = {name: ResourceSlot(name, d, Codec(model.resource_by_name[name])) for name, d in drivers.items()}
        self.selftest_reports: list[SelftestReport] = []
        self.authority = Authority(hub, self.keys)
        self._tasks: list[asyncio.Task[None]] = []
        self.notifier = Notifier()  # systemd's READY=1 and watchdog, under a unit only

    # --- lifecycle ------------------------------------------------------------------------
    async def run(self, stop: asyncio.Event) -> None:
        for slot in self.slots.values():
            await slot.driver.connect()
        token = self.bus.declare_liveliness(self.keys.alive(self.hub))
        try:
            await self._start_in_safe_state()
            self.notifier.ready()
            self._tasks = [asyncio.create_task(self.authority.follow(self.bus), name="holder")]
            self._tasks += [asyncio.create_task(self._commands(slot), name=f"commands {slot.name}")
                            for slot in self.slots.values()]
            self._tasks += [asyncio.create_task(self._external_inputs(), name="inputs")]
            self._tasks += [asyncio.create_task(self._supervisor_calls(slot), name=f"calls {slot.name}")
                            for slot in self.slots.values() if isinstance(slot.driver, CallsSupervisor)]
            self._tasks.append(asyncio.create_task(self._selftest(), name="selftest"))
            self._tasks.append(asyncio.create_task(self._publish_loop(), name="publish"))
            # The publish loop sleeps between periods instead of waiting on `stop` (a task and a
            # timeout every 20 ms); stopping cancels it. A crash of any task ends the hub.
            await wait_for_stop_or_crash(stop, self._tasks)
        finally:
            await cancel_and_wait(self._tasks, TASKS_END_S, log)
            # Stopped or crashed: no output may stay as the last command left it.
            await safe_state_on_exit(self.hub, [slot.driver for slot in self.slots.values()])
            token.undeclare()
            await close_drivers([slot.driver for slot in self.slots.values()], DRIVER_CLOSE_S)

    async def _start_in_safe_state(self) -> None:
        for slot in self.slots.values():
            await self._drive_safe_state(slot, HubStatus.NO_COMMAND, "no command received since the hub started")

    async def _selftest(self) -> None:
        """Run the self-test once the devices had a moment to connect, publish it, and answer queries for it."""
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline and not all(s.driver.connected for s in self.slots.values()):
            await asyncio.sleep(0.05)
        reports = []
        for slot in self.slots.values():
            try:
                reports.append(await slot.driver.selftest())
            except Exception as exc:  # a failing self-test is a report, not a crash
                failed = SelftestReport(slot.name)
                failed.add("self-test ran", False, f"{type(exc).__name__}: {exc}")
                reports.append(failed)
        self.selftest_reports = reports
        payload = encode(report_message(self.hub, reports))
        self.bus.publish(self.keys.selftest(self.hub), payload, block=True)

        async def answer(_request: Request) -> bytes:
            return payload

        self.bus.declare_queryable(self.keys.selftest(self.hub), answer)

    # --- commands -------------------------------------------------------------------------
    async def _commands(self, slot: ResourceSlot) -> None:
        async for sample in self.bus.subscribe(self.keys.cmd(slot.name)):
            await asyncio.sleep(0)  # a flood of commands must not starve the publish loop
            try:
                command = self.authority.decode(slot.codec, sample)  # None: dropped (logged)
            except (DomainError, ModelMismatch) as exc:
                # The holder's, but nothing of it is applied: the mirror stays the last applied command.
                # The status says whose command was refused.
                slot.status, slot.detail = HubStatus.REJECTED, f"command{_sender(exc)} refused: {exc}"
                self._publish(slot)
                continue
            if command is None or self._is_older(slot, command):
                continue
            # The command timeout is about a silent controller: a command that arrived counts even while
            # the device cannot take it (it is applied when the device is back, the controller is alive).
            slot.last_command_at = time.monotonic()
            values = slot.codec.values(command)
            # While a write takes its time (a slow device, bounded by the driver's own timeouts) the newer
            # commands wait behind it: that is no silence either, and a safe state driven meanwhile would
            # undo what the write is doing (a mission paused as it is posted).
            slot.applying = True
            try:
                await slot.driver.write(values)
            except DeviceUnavailable as exc:
                slot.device_problem = str(exc) or "device does not answer"
                self._publish(slot)
                continue
            except Exception as exc:
                log.exception("hub %s: driver of %s failed to apply a command", self.hub, slot.name)
                slot.status, slot.detail = HubStatus.ERROR, f"{type(exc).__name__}: {exc}"
                self._publish(slot)
                continue
            finally:
                slot.applying = False
            slot.mirror = command
            slot.last_command_at = time.monotonic()
            slot.in_safe_state = False
            slot.status, slot.detail = HubStatus.OK, ""
            self._publish(slot)

    @staticmethod
    def _is_older(slot: ResourceSlot, command: CommandMessage) -> bool:
        # Ordered per (controller, epoch): a new holder's first command is never older.
        mirror = slot.mirror
        if mirror is None or (mirror.controller, mirror.epoch) != (command.controller, command.epoch):
            return False
        return command.seq < mirror.seq

    async def _drive_safe_state(self, slot: ResourceSlot, status: HubStatus, detail: str) -> None:
        # The driver stops and drives what it calls safe; nothing else is written (re-writing the last
        # command would restart a motion the driver just stopped, the model's initial values could drop
        # a tool). The mirror follows what it applied, so that it never claims a command still in force.
        try:
            applied = await slot.driver.enter_safe_state()
        except DeviceUnavailable as exc:
            slot.device_problem = str(exc) or "device does not answer"
            return
        except Exception as exc:
            log.exception("hub %s: could not drive the safe state of %s", self.hub, slot.name)
            slot.status, slot.detail = HubStatus.ERROR, f"safe state failed: {exc}"
            return
        mirror = slot.mirror
        if mirror is not None and applied:
            try:  # checked like a command: a driver's slip must not put a value outside its domain on the wire
                slot.mirror = slot.codec.command({**slot.codec.values(mirror), **applied}, seq=mirror.seq,
                                                 controller=mirror.controller, epoch=mirror.epoch,
                                                 time=mirror.time)
            except MessageError as exc:
                log.error("hub %s: the safe state of %s applied what is no command: %s", self.hub, slot.name, exc)
                slot.in_safe_state = True  # it did stop; only its report is wrong
                slot.status, slot.detail = HubStatus.ERROR, f"safe state: {exc}"
                return
        slot.in_safe_state = True
        slot.status, slot.detail = status, detail

    # --- inputs of emulated devices that depend on other resources -------------------------
    async def _external_inputs(self) -> None:
        wanted: dict[str, set[str]] = {}
        estimated: set[str] = set()
        for slot in self.slots.values():
            if not isinstance(slot.driver, Inputs):
                continue
            for path in slot.driver.inputs:
                if self.model.var(path).kind is Kind.ESTIMATED:
                    estimated.add(path)  # the controller's (e.g. engine.frame_e): from its state snapshots
                else:
                    wanted.setdefault(path.split(".", 1)[0], set()).add(path)
        subscriptions = [self._follow_estimated(estimated)] if estimated else []
        codecs = {r: Codec(self.model.resource_by_name[r]) for r in wanted}
        for resource, paths in wanted.items():
            kinds = {self.model.var(p).kind for p in paths}
            codec = codecs[resource]
            if Kind.MEASURED in kinds:
                subscriptions.append(self._follow(self.keys.state(resource), codec, codec.decode_state))
            if Kind.COMMAND in kinds:
                subscriptions.append(self._follow(self.keys.cmd(resource), codec, codec.decode_command))
        await asyncio.gather(*subscriptions)

    async def _follow_estimated(self, paths: set[str]) -> None:
        async for sample in self.bus.subscribe(self.keys.ctl("state")):
            try:
                snapshot = decode(sample.payload, StateSnapshot)
            except MessageError as exc:
                log.debug("hub %s: ignored %s: %s", self.hub, sample.key, exc)
                continue
            values = {p: v for p, v in snapshot.values.items() if p in paths}
            if values:
                self._observed(values, snapshot.time)

    async def _follow(self, key: str, codec: Codec,
                      decode_message: Callable[[bytes], CommandMessage | StateMessage]) -> None:
        """Another resource's states or commands (`key`, read by `decode_message`): their values, to the
        drivers that observe them."""
        async for sample in self.bus.subscribe(key):
            try:
                message = decode_message(sample.payload)
            except MessageError as exc:
                log.debug("hub %s: ignored %s: %s", self.hub, sample.key, exc)
                continue
            values = {p: v for p, v in codec.values(message, paths=True).items() if v is not None}
            self._observed(values, message.time)

    def _observed(self, values: Mapping[str, Value], published_at: float) -> None:
        for slot in self.slots.values():
            if isinstance(slot.driver, Observes):
                slot.driver.observe(values, published_at)

    # --- an operator's call for the supervisor -------------------------------------------------
    async def _supervisor_calls(self, slot: ResourceSlot) -> None:
        """A liveliness token while the call stands: the controller hears it begin and end, and a restarted
        controller finds it still standing."""
        assert isinstance(slot.driver, CallsSupervisor)
        token = None
        try:
            while True:
                calling = await slot.driver.next_call()
                if calling and token is None:
                    token = self.bus.declare_liveliness(self.keys.call(self.hub, slot.name))
                elif not calling and token is not None:
                    token.undeclare()
                    token = None
        finally:
            if token is not None:
                token.undeclare()

    # --- state out ------------------------------------------------------------------------
    async def _publish_loop(self) -> None:
        """Every period: drive the safe state where commands stopped, then read and publish each
        resource, on fixed deadlines (no drift). An applied command is published at once by `_commands`."""
        loop = asyncio.get_running_loop()
        next_at = loop.time()
        while True:
            self.notifier.alive()
            now = time.monotonic()
            for slot in self.slots.values():
                if slot.last_command_at is not None and not slot.in_safe_state and not slot.applying \
                        and now - slot.last_command_at > self.command_timeout:
                    log.warning("hub %s: no command for %s within %.2f s: safe state", self.hub, slot.name,
                                self.command_timeout)
                    await self._drive_safe_state(slot, HubStatus.SAFE_STATE,
                                                 f"no command within {self.command_timeout} s")
                await self._read_and_publish(slot)
            next_at += self.period
            now = loop.time()
            if next_at < now - self.period:  # fell behind (a pause): do not try to catch up
                next_at = now
            wake_at = max(next_at, now)
            await asyncio.sleep(wake_at - now)  # <= 0: yields once, so commands are never starved
            self._not_counted_as_silence(loop.time() - wake_at)

    def _not_counted_as_silence(self, late: float) -> None:
        """This wake-up came `late` s after its time: the hub itself did not run (its process starved
        of CPU, or its loop blocked). Commands that arrived meanwhile still wait behind this wake-up, so
        the gap is not the controller's silence and does not count toward the command timeout."""
        if late <= self.period:  # ordinary scheduling jitter counts as usual
            return
        for slot in self.slots.values():
            if slot.last_command_at is not None:
                slot.last_command_at += late

    async def _read_and_publish(self, slot: ResourceSlot) -> None:
        try:
            slot.measured = await slot.driver.read()
            slot.device_problem = None
        except DeviceUnavailable as exc:
            slot.measured = {}  # unknown: stale values are never published as fresh
            slot.device_problem = str(exc) or "device does not answer"
        except Exception as exc:  # a driver bug: the hub reports it and keeps serving its other devices
            fault = f"driver failed to read: {type(exc).__name__}: {exc}"
            if fault != slot.driver_fault:  # logged once per distinct failure, not at the read rate
                log.exception("hub %s: driver of %s failed to read", self.hub, slot.name)
            slot.measured, slot.driver_fault, slot.device_problem = {}, fault, None
        else:
            slot.driver_fault = None
        self._publish(slot)

    def _publish(self, slot: ResourceSlot) -> None:
        slot.seq += 1
        status, detail = slot.status, slot.detail
        if slot.device_problem is not None:
            status, detail = HubStatus.DEVICE_LOST, slot.device_problem
        elif slot.driver_fault is not None:
            status, detail = HubStatus.ERROR, slot.driver_fault
        try:
            message = slot.codec.state(slot.measured, status=status, detail=detail[:500], seq=slot.seq,
                                       hub=self.hub, mirror=slot.mirror)
        except MessageError as exc:
            log.error("hub %s: driver of %s read a value outside the model: %s", self.hub, slot.name, exc)
            message = slot.codec.state({}, status=HubStatus.ERROR, detail=str(exc)[:500], seq=slot.seq,
                                       hub=self.hub, mirror=slot.mirror)
        self.bus.publish(self.keys.state(slot.name), slot.codec.encode_state(message))


def _sender(exc: MessageError) -> str:
    """` seq 7 from ctl-1a2b` for a refused command whose envelope was readable, else ""."""
    if not isinstance(exc, DomainError) or exc.controller is None:
        return ""
    controller = exc.controller if len(exc.controller) <= 64 else exc.controller[:61] + "..."  # may be garbage
    return f" seq {exc.seq} from {controller}" if exc.seq is not None else f" from {controller}"


__all__ = ["HubRuntime", "SelftestMessage"]
