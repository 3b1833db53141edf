"""The simulated cell: how the device simulators are coupled physically, as in the real cell.

Each simulator speaks its device's protocol on its own (``hubs/sim/*``); in the real cell
the devices also act on each other through the physical world. This module is that
world, talking to the simulators through their side channels only (never through a
device protocol the hubs use):

* **Flange** (``FlangeCoupling``): the tool changer sees which dock slot the robot's
  flange is at. It subscribes to the fake UR controller's flange slot (command port,
  ``{"cmd": "watch_flange"}``, ``hubs.sim.ur_flange``) and writes the Modbus coupler's
  flange register (holding register 0: 0 away, n at slot n) at each change before it
  acknowledges it; the fake's RTDE streams wait for that acknowledgement, so nobody sees
  the robot at a slot before the changer does. The dock's slot sensors follow from the
  coupler's physics.
* **Operator** (``OperatorCoupling``): the operator is an emulated resource (there is
  no protocol for a human), but the devices that sense the operator are simulated. It
  follows the instruction the operator's hub applied (``{station}/res/{operator}/state``,
  the mirror) and

  - walks to the zone of the instruction's task (the camera model's ``task_zones``;
    none: out of the cell), along a corridor outside every zone so that the camera
    never sees a zone on the way that the model does not expect; the positions go to
    the tracker simulator (``--control``, JSON lines on its stdin);
  - takes a tool out of its dock slot by hand while a task of the dock model's
    ``handheld_tasks`` is instructed (coupler holding register 2), and puts it back
    after.
* **Badge** (``BadgeCoupling``): the operator presents the badge to the RFID reader
  whenever the reader's resource reports nobody verified (the model's effect:
  ``!verified_m`` → ``verified_m``), at most once per ``retry`` s so that one scan is
  never read as badge-in and badge-out.

Every coupling is a coroutine that runs until cancelled and survives a simulator or
the bus going away (it logs once and retries).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import time
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass, field

from pymodbus.client import AsyncModbusTcpClient
from pymodbus.exceptions import ModbusException

from common.bus.protocol import Bus
from common.wire.keys import Keys
from common.wire.messages import Codec, HubStatus, MessageError
from hubs.protocols.coupler import DEVICE_ID, TOOLS
from hubs.sim.toolchanger_modbus import HR_FLANGE, HR_HAND

log = logging.getLogger("statehub.simworld")

Send = Callable[[str], Awaitable[None]]  # one line to a simulator's control input
Point = tuple[float, float]
Rect = Sequence[float]  # x0, y0, x1, y1


class CouplerLink:
    """Writes the simulator-only holding registers of the Modbus coupler simulator."""

    def __init__(self, host: str, port: int, device_id: int = DEVICE_ID) -> None:
        self.host, self.port, self.device_id = host, port, device_id
        self._client: AsyncModbusTcpClient | None = None
        self._lock = asyncio.Lock()
        self._complained = False

    async def write(self, register: int, value: int) -> bool:
        async with self._lock:
            try:
                if self._client is None or not self._client.connected:
                    self._client = AsyncModbusTcpClient(self.host, port=self.port, timeout=1, retries=0,
                                                        reconnect_delay=0)
                    if not await self._client.connect():
                        raise ConnectionError("connection refused")
                result = await self._client.write_register(register, value, device_id=self.device_id)
                if result.isError():
                    raise ModbusException(str(result))
            except (TimeoutError, ConnectionError, OSError, ModbusException) as exc:
                self.close()
                if not self._complained:
                    log.warning("coupler simulator %s:%d: cannot write register %d: %s", self.host, self.port,
                                register, exc)
                    self._complained = True
                return False
            self._complained = False
            return True

    def close(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            client.close()


class RobotLink:
    """Reads the fake UR controller's joint positions through its command port."""

    def __init__(self, host: str, port: int, timeout: float = 1.0) -> None:
        self.host, self.port, self.timeout = host, port, timeout
        self._streams: tuple[asyncio.StreamReader, asyncio.StreamWriter] | None = None

    async def joints(self) -> list[float] | None:
        try:
            # asyncio.timeout, not wait_for: Python 3.11's wait_for loses a cancellation that comes as the
            # reply does, and this link is polled every 10 ms by a task the world cancels when it stops.
            if self._streams is None:
                async with asyncio.timeout(self.timeout):
                    self._streams = await asyncio.open_connection(self.host, self.port)
            reader, writer = self._streams
            writer.write(b'{"cmd": "pose"}\n')
            await writer.drain()
            async with asyncio.timeout(self.timeout):
                line = await reader.readline()
            reply = json.loads(line)
            return [float(v) for v in reply["q"]]
        except (TimeoutError, OSError, ValueError, KeyError, TypeError):
            self.close()
            return None

    def close(self) -> None:
        streams, self._streams = self._streams, None
        if streams is not None:
            streams[1].close()


@dataclass
class FlangeCoupling:
    """The robot's dock slot → the coupler's flange register. `slots`: dock slot number → the joint target of
    its pose.

    Subscribed on the fake controller's command port (``hubs.sim.ur_flange``), not polled: its RTDE streams
    wait until this has written the register, so that nobody sees the robot at a slot before the changer
    does (polled, a controller under load could unlock the changer first and the tool fell)."""

    robot: RobotLink
    coupler: CouplerLink
    slots: Mapping[int, Sequence[float]]
    tolerance: float = 0.01
    retry: float = 0.5  # s before trying a robot or a coupler again that did not answer

    async def run(self) -> None:
        while True:
            try:
                await self._follow()
            except (TimeoutError, ConnectionError, OSError, ValueError, KeyError, TypeError) as exc:
                log.debug("flange watch of %s:%d: %s", self.robot.host, self.robot.port, exc)
            await asyncio.sleep(self.retry)

    async def _follow(self) -> None:
        async with asyncio.timeout(1.0):
            reader, writer = await asyncio.open_connection(self.robot.host, self.robot.port)
        try:
            request = {"cmd": "watch_flange", "slots": {str(n): list(q) for n, q in self.slots.items()},
                       "tolerance": self.tolerance}
            writer.write(json.dumps(request).encode() + b"\n")
            await writer.drain()
            async with asyncio.timeout(1.0):
                if not json.loads(await reader.readline()).get("ok"):
                    raise ValueError("watch_flange refused")
            slot: int | None = None
            written: int | None = None
            while True:
                line: bytes | None = None
                with contextlib.suppress(TimeoutError):  # a write that failed is tried again meanwhile
                    async with asyncio.timeout(self.retry if slot != written else None):
                        line = await reader.readline()
                if line is not None:
                    if not line:
                        raise ConnectionError("the robot closed its flange watch")
                    slot = int(json.loads(line)["slot"])
                if slot is not None and slot != written and await self.coupler.write(HR_FLANGE, slot):
                    log.debug("flange at slot %d", slot)
                    written = slot
                if line is not None:  # acknowledged even when the coupler is away: the robot is not held
                    writer.write(json.dumps({"ack": slot}).encode() + b"\n")
                    await writer.drain()
        finally:
            writer.close()


# --- the operator as the camera sees them --------------------------------------------------

@dataclass
class Walker:
    """The operator's position: walks to a spot per zone along a corridor outside every zone."""

    zones: Mapping[str, Sequence[Rect]]
    speed: float = 1.4  # m/s
    position: Point = (0.0, 0.0)
    route: list[Point] = field(default_factory=list)

    def __post_init__(self) -> None:
        rects = [r for rs in self.zones.values() for r in rs]
        if not rects:
            raise ValueError("the camera has no zones")
        self.corridor = max(max(r[1], r[3]) for r in rects) + 0.5
        self.position = self.spot("outside")

    def spot(self, zone: str) -> Point:
        """Where the operator stands in `zone`: the centre of its first rectangle; outside: in the corridor."""
        if self.zones.get(zone):
            x0, y0, x1, y1 = self.zones[zone][0]
            return ((x0 + x1) / 2, (y0 + y1) / 2)
        first = next(rs[0] for rs in self.zones.values() if rs)
        return ((first[0] + first[2]) / 2, self.corridor)

    def zone_at(self, point: Point) -> str:
        x, y = point
        inside = [z for z, rs in self.zones.items()
                  if any(min(r[0], r[2]) <= x <= max(r[0], r[2]) and min(r[1], r[3]) <= y <= max(r[1], r[3])
                         for r in rs)]
        return next((z for z in ("robot", "shared") if z in inside), inside[0] if inside else "outside")

    def go(self, zone: str) -> None:
        """Head for `zone`: straight there within the zone, else out to the corridor, along it, and in."""
        target = self.spot(zone)
        if self.zone_at(self.position) == zone:
            waypoints = [target]
        else:
            waypoints = [(self.position[0], self.corridor), (target[0], self.corridor), target]
        self.route = []
        for point in waypoints:
            if point != (self.route[-1] if self.route else self.position):
                self.route.append(point)

    def step(self, dt: float) -> bool:
        """Walk for `dt` s; True when the position changed."""
        budget, moved = self.speed * dt, False
        while self.route and budget > 0:
            (x, y), (tx, ty) = self.position, self.route[0]
            gap = math.hypot(tx - x, ty - y)
            if gap <= budget:
                self.position, budget = (tx, ty), budget - gap
                self.route.pop(0)
            else:
                self.position = (x + (tx - x) * budget / gap, y + (ty - y) * budget / gap)
                budget = 0
            moved = True
        return moved


def applied_instruction(codec: Codec, payload: bytes, command: str = "instr_c", idle: str = "none") -> str | None:
    """The instruction an operator's hub applied, from its state message; None for a message it cannot read.
    A hub in its safe state (no command yet, or the controller went silent) has withdrawn it."""
    try:
        state = codec.decode_state(payload)
    except MessageError:
        return None
    if state.status in (HubStatus.NO_COMMAND, HubStatus.SAFE_STATE) or state.mirror is None:
        return idle
    return str(getattr(state.mirror, command))


@dataclass
class OperatorCoupling:
    """Follows the emulated operator's instruction: walks it in front of the cameras, takes tools by hand."""

    bus: Bus
    keys: Keys
    codec: Codec
    task_zones: Mapping[str, str]
    walker: Walker | None
    cameras: Sequence[Send]
    handheld: Mapping[str, Sequence[str]]  # tool -> tasks it is held for
    couplers: Sequence[CouplerLink]
    rate: float = 20.0
    instruction: str = "none"

    async def run(self) -> None:
        await asyncio.gather(self._follow(), self._walk())

    async def _follow(self) -> None:
        async for sample in self.bus.subscribe(self.keys.state(self.codec.resource)):
            instruction = applied_instruction(self.codec, sample.payload)
            if instruction is None or instruction == self.instruction:
                continue
            log.info("operator: %s -> %s", self.instruction, instruction)
            self.instruction = instruction
            if self.walker is not None:
                self.walker.go(self.task_zones.get(instruction, "outside"))
            await self._hands()

    async def _hands(self) -> None:
        held = {t for t, tasks in self.handheld.items() if self.instruction in tasks}
        mask = sum(1 << i for i, tool in enumerate(TOOLS) if tool in held)
        for coupler in self.couplers:
            await coupler.write(HR_HAND, mask)

    async def _walk(self) -> None:
        if self.walker is None:
            return
        await self._show()
        last = time.monotonic()
        while True:
            await asyncio.sleep(1.0 / self.rate)
            now = time.monotonic()
            if self.walker.step(now - last):
                await self._show()
            last = now

    async def _show(self) -> None:
        assert self.walker is not None
        x, y = self.walker.position
        line = json.dumps({"person": 1, "x": round(x, 3), "y": round(y, 3)})
        for send in self.cameras:
            with contextlib.suppress(OSError, ConnectionError):
                await send(line)


@dataclass
class BadgeCoupling:
    """The operator badges in at the RFID reader whenever its resource reports nobody verified."""

    bus: Bus
    keys: Keys
    codec: Codec
    scan: Send
    tag: str
    delay: float = 0.5  # s from seeing nobody verified to the scan
    retry: float = 3.0  # s before scanning again (more than the reader's repeat window)

    async def run(self) -> None:
        unverified_since: float | None = None
        last_scan = -math.inf
        async for sample in self.bus.subscribe(self.keys.state(self.codec.resource)):
            try:
                state = self.codec.decode_state(sample.payload)
            except MessageError:
                continue
            now = time.monotonic()
            if self.codec.values(state)["verified_m"] is not False:  # verified, or the reader does not answer
                unverified_since = None
                continue
            unverified_since = unverified_since if unverified_since is not None else now
            if now - unverified_since >= self.delay and now - last_scan >= self.retry:
                log.info("operator: badge %s presented to %s", self.tag, self.codec.resource)
                with contextlib.suppress(OSError, ConnectionError):
                    await self.scan(self.tag)
                last_scan = now

