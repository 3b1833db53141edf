"""Lifting system on CAN (python-can; ``socketcan`` on the Pi, ``virtual`` in sim mode).

Frame map: ``hubs.protocols.lift_can`` (command 0x200 + N, status 0x180 + N every
20 ms, NMT heartbeat 0x700 + N every 100 ms, around the lift's node id N, default 0x10).

The lift runs a command watchdog: with no command frame for 0.5 s it stops.  The
driver therefore repeats the command in force every ``command_period`` (0.1 s).

Mapping: ``ref_c = up`` → command 1, ``down`` → command 2 (the lift stops at the limit
switch by itself); ``pos_m`` = ``up`` when the upper limit switch is on, ``down`` when
the lower one is, else ``between``.  A fault flag makes ``read`` raise
``DeviceUnavailable`` naming the fault code (the contract has no fault variable; the
controller sees the resource unhealthy).

Device lost: no heartbeat for ``heartbeat_timeout`` (0.35 s), no status frame for
``status_timeout`` (0.1 s), a heartbeat other than operational, or a bus error: the
next ``read`` raises ``DeviceUnavailable`` and the shared ReconnectLogic reopens the
bus and waits for the heartbeat again.  A silence is judged after one wait of half the
status timeout, so that frames that came while the hub's loop was busy count.

Safe state: ``enter_safe_state()`` sends *stop* at once and keeps sending it instead of
the target (also after a reconnect); ``ref_c`` keeps its value (it returns ``{}``).  The
next command resumes motion toward its ``ref_c``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import struct
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Annotated, Any

import can
import msgspec

from common.model import Value
from hubs.drivers.base import DeviceUnavailable, SelftestReport
from hubs.drivers.params import DriverParams, Positive
from hubs.drivers.reconnect import Backoff, LinkedDriver, ReconnectLogic, describe
from hubs.drivers.registry import DriverPlugin
from hubs.protocols.lift_can import (
    CMD_DOWN,
    CMD_STOP,
    CMD_UP,
    COB_COMMAND,
    COB_HEARTBEAT,
    COB_STATUS,
    DEFAULT_NODE,
    FLAG_FAULT,
    FLAG_LOWER,
    FLAG_MOVING_DOWN,
    FLAG_MOVING_UP,
    FLAG_UPPER,
    NMT_OPERATIONAL,
    STATUS_FORMAT,
)

log = logging.getLogger(__name__)

COMMANDS = {"up": CMD_UP, "down": CMD_DOWN}

BusFactory = Callable[[], can.BusABC]


@dataclass(frozen=True)
class LiftStatus:
    position_mm: int
    upper: bool
    lower: bool
    moving_up: bool
    moving_down: bool
    fault: bool
    fault_code: int
    echo_command: int
    echo_seq: int
    received: float

    @classmethod
    def decode(cls, data: bytes | bytearray, received: float) -> LiftStatus:
        if len(data) < 6:
            raise ValueError(f"status frame too short ({len(data)} bytes)")
        position, flags, code, echo, seq = struct.unpack_from(STATUS_FORMAT, data)
        return cls(
            position,
            bool(flags & FLAG_UPPER),
            bool(flags & FLAG_LOWER),
            bool(flags & FLAG_MOVING_UP),
            bool(flags & FLAG_MOVING_DOWN),
            bool(flags & FLAG_FAULT),
            code,
            echo,
            seq,
            received,
        )


class _Listener(can.Listener):
    """Hands frames to the driver (on the event loop) and reports bus errors as a lost device."""

    def __init__(self, on_message: Callable[[can.Message], None], link: ReconnectLogic) -> None:
        self._on_message = on_message
        self._link = link

    def on_message_received(self, msg: can.Message) -> None:
        self._on_message(msg)

    def on_error(self, exc: Exception) -> None:
        self._link.connection_lost_threadsafe(f"CAN bus error: {describe(exc)}")


class LiftCan(LinkedDriver[ReconnectLogic]):
    def __init__(
        self,
        resource: str = "lift",
        *,
        node_id: int = DEFAULT_NODE,
        bus_factory: BusFactory,
        where: str = "can0",
        heartbeat_timeout: float = 0.35,
        status_timeout: float = 0.1,
        command_period: float = 0.1,
        backoff: Backoff | None = None,
    ) -> None:
        self.resource = resource
        self.node_id = node_id
        self.where = where
        self.heartbeat_timeout = heartbeat_timeout
        self.status_timeout = status_timeout
        self.command_period = command_period
        self._bus_factory = bus_factory
        self._bus: can.BusABC | None = None
        self._notifier: can.Notifier | None = None
        self._keepalive: asyncio.Task[None] | None = None
        self._status: LiftStatus | None = None
        self._heartbeat: tuple[int, float] | None = None  # (NMT state, monotonic time)
        self._heartbeat_seen = asyncio.Event()
        self._desired: str | None = None  # last commanded ref_c
        self._held = False  # safe state entered: send stop until the next write
        self._seq = 0
        self._sent: dict[int, int] = {}  # seq -> command, the last 256 sent
        self._link = ReconnectLogic(
            f"{resource}@{where}:node 0x{node_id:02x}",
            self._open,
            self._release,
            backoff=backoff,
            connect_timeout=max(2.0, 3 * heartbeat_timeout),
        )

    # -- Driver API -------------------------------------------------------------------

    async def read(self) -> Mapping[str, Value]:
        status = await self._current_status()
        if status.fault:
            raise DeviceUnavailable(f"{self.resource}: lift reports fault code {status.fault_code}")
        if status.upper and status.lower:
            raise DeviceUnavailable(f"{self.resource}: both limit switches on (sensor fault)")
        pos = "up" if status.upper else "down" if status.lower else "between"
        return {"pos_m": pos}

    async def write(self, commands: Mapping[str, Value]) -> None:
        if "ref_c" not in commands:
            return
        ref = str(commands["ref_c"])
        if ref not in COMMANDS:
            raise ValueError(f"{self.resource}: ref_c must be one of {sorted(COMMANDS)}, got {ref!r}")
        self._desired, self._held = ref, False
        if not self.connected:
            raise DeviceUnavailable(f"{self.resource}: lift not connected ({self._link.last_error})")
        self._send_command(COMMANDS[ref])

    async def enter_safe_state(self) -> Mapping[str, Value]:
        self._held = True  # stop instead of the target until the next command, also after a reconnect
        if self.connected:
            with contextlib.suppress(DeviceUnavailable):
                self._send_command(CMD_STOP)
        return {}

    async def selftest(self) -> SelftestReport:
        report = SelftestReport(self.resource)
        if not await self._link.wait_attempt():
            report.add(
                "device answers",
                False,
                f"no heartbeat from node 0x{self.node_id:02x} on {self.where}: {self._link.last_error}",
            )
            report.add("inputs read", False, "not checked: device absent")
            report.add("outputs read back", False, "not checked: device absent")
            return report
        report.add("device answers", True, f"node 0x{self.node_id:02x} on {self.where} operational")
        try:
            values = await self.read()
            status = await self._current_status()
            report.add("inputs read", True, f"pos_m={values['pos_m']}, position {status.position_mm} mm")
        except DeviceUnavailable as exc:
            report.add("inputs read", False, str(exc))
        # Read back: the command in force (stop when none) must come back in the status echo.
        command = self._command_in_force()
        try:
            seq = self._send_command(command)
            deadline = time.monotonic() + max(0.5, 10 * self.status_timeout)
            while time.monotonic() < deadline:
                latest = self._status
                if latest is not None and self._echoes_since(latest, seq):
                    report.add("outputs read back", True,
                               f"command {latest.echo_command} (seq {latest.echo_seq}) echoed")
                    break
                await asyncio.sleep(0.01)
            else:
                echo = self._status
                got = f"echo command {echo.echo_command} seq {echo.echo_seq}" if echo else "no status"
                report.add("outputs read back", False, f"command {command} seq {seq} not echoed ({got})")
        except DeviceUnavailable as exc:
            report.add("outputs read back", False, str(exc))
        return report

    # -- protocol ---------------------------------------------------------------------

    def _command_in_force(self) -> int:
        if self._held or self._desired is None:
            return CMD_STOP
        return COMMANDS[self._desired]

    def _send_command(self, command: int) -> int:
        bus = self._bus
        if bus is None:
            raise DeviceUnavailable(f"{self.resource}: bus not open")
        self._seq = (self._seq + 1) & 0xFF
        self._sent[self._seq] = command
        msg = can.Message(arbitration_id=COB_COMMAND + self.node_id, data=[command, self._seq], is_extended_id=False)
        try:
            bus.send(msg, timeout=0.05)
        except can.CanError as exc:
            self._link.connection_lost(f"send failed: {describe(exc)}")
            raise DeviceUnavailable(f"{self.resource}: {describe(exc)}") from exc
        return self._seq

    def _echoes_since(self, status: LiftStatus, seq: int) -> bool:
        """The status echoes the command sent as ``seq`` or one sent after it (a command written
        meanwhile, or the keepalive's), as it was sent."""
        if (status.echo_seq - seq) & 0xFF > (self._seq - seq) & 0xFF:
            return False
        return self._sent.get(status.echo_seq) == status.echo_command

    async def _current_status(self) -> LiftStatus:
        """The latest status, if the lift is alive.

        Frames are stamped when the event loop takes them: after the loop was busy (a long GC, a
        starved process) the frames that came meanwhile are still waiting to be handed over, so a
        status that looks old gets one short wait for them before the lift is declared lost."""
        if not self.connected:
            raise DeviceUnavailable(f"{self.resource}: lift not connected ({self._link.last_error})")
        if self._silence() is not None:
            await asyncio.sleep(self.status_timeout / 2)
        reason = self._silence()
        if reason is not None:
            self._link.connection_lost(reason)
            raise DeviceUnavailable(f"{self.resource}: {reason}")
        assert self._status is not None
        return self._status

    def _silence(self) -> str | None:
        """Why the lift looks lost now, or None."""
        now = time.monotonic()
        if self._heartbeat is None or now - self._heartbeat[1] > self.heartbeat_timeout:
            return f"no heartbeat for {self.heartbeat_timeout} s"
        if self._heartbeat[0] != NMT_OPERATIONAL:
            return f"node not operational (NMT state {self._heartbeat[0]:#04x})"
        if self._status is None or now - self._status.received > self.status_timeout:
            return f"no status frame for {self.status_timeout} s"
        return None

    def _on_message(self, msg: can.Message) -> None:
        """Runs on the event loop (the Notifier hands messages over with ``loop=``)."""
        now = time.monotonic()
        if msg.arbitration_id == COB_HEARTBEAT + self.node_id and msg.dlc >= 1:
            self._heartbeat = (msg.data[0], now)
            if msg.data[0] == NMT_OPERATIONAL:
                self._heartbeat_seen.set()
        elif msg.arbitration_id == COB_STATUS + self.node_id:
            try:
                self._status = LiftStatus.decode(msg.data, now)
            except (ValueError, struct.error) as exc:
                log.warning("%s: bad status frame %s: %s", self.resource, msg.data.hex(), exc)

    async def _keepalive_loop(self) -> None:
        while True:
            await asyncio.sleep(self.command_period)
            if not self.connected:
                continue
            if self._desired is not None or self._held:
                with contextlib.suppress(DeviceUnavailable):
                    self._send_command(self._command_in_force())
            with contextlib.suppress(DeviceUnavailable):
                await self._current_status()  # notices a silent lift even when nobody reads

    # -- connection -------------------------------------------------------------------

    async def _open(self) -> None:
        self._status, self._heartbeat = None, None
        self._heartbeat_seen.clear()
        bus = await asyncio.to_thread(self._bus_factory)
        self._bus = bus
        ids = (COB_STATUS + self.node_id, COB_HEARTBEAT + self.node_id)
        bus.set_filters([{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in ids])
        self._notifier = can.Notifier(
            bus, [_Listener(self._on_message, self._link)], timeout=0.05, loop=asyncio.get_running_loop()
        )
        try:
            async with asyncio.timeout(self.heartbeat_timeout * 2):
                await self._heartbeat_seen.wait()
        except TimeoutError:
            raise ConnectionError(f"no operational heartbeat from node 0x{self.node_id:02x}") from None
        status_deadline = time.monotonic() + max(self.status_timeout * 3, 0.2)
        while self._status is None and time.monotonic() < status_deadline:
            await asyncio.sleep(0.005)
        if self._status is None:
            raise ConnectionError(f"heartbeat but no status frames from node 0x{self.node_id:02x}")
        if self._desired is not None or self._held:
            self._send_command(self._command_in_force())
        if self._keepalive is None or self._keepalive.done():
            self._keepalive = asyncio.create_task(self._keepalive_loop(), name=f"keepalive:{self.resource}")

    async def _release(self) -> None:
        task, self._keepalive = self._keepalive, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        notifier, self._notifier = self._notifier, None
        bus, self._bus = self._bus, None

        def shutdown() -> None:  # one thread call: finishes even if this coroutine is cancelled
            if notifier is not None:
                notifier.stop(1.0)
            if bus is not None:
                bus.shutdown()

        await asyncio.to_thread(shutdown)
        self._status = None
        self._heartbeat = None


class LiftParams(DriverParams, frozen=True, kw_only=True):
    interface: str = "socketcan"  # python-can interface
    channel: str = "can0"
    node_id: Annotated[int, msgspec.Meta(ge=1, le=0x7F)] = DEFAULT_NODE
    bitrate: Annotated[int, msgspec.Meta(gt=0)] | None = None
    heartbeat_timeout: Positive = 0.35
    status_timeout: Positive = 0.1
    command_period: Positive = 0.1


def build(resource: str, params: LiftParams) -> LiftCan:
    extra: dict[str, Any] = {} if params.bitrate is None else {"bitrate": params.bitrate}

    def factory() -> can.BusABC:
        return can.Bus(interface=params.interface, channel=params.channel, **extra)

    return LiftCan(
        resource,
        node_id=params.node_id,
        bus_factory=factory,
        where=f"{params.interface}:{params.channel}",
        heartbeat_timeout=params.heartbeat_timeout,
        status_timeout=params.status_timeout,
        command_period=params.command_period,
        backoff=params.backoff(),
    )


PLUGIN = DriverPlugin(LiftParams, build)
