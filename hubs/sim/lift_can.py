"""A simulated lifting system on python-can's ``virtual`` interface.

Speaks the frame map of ``hubs.protocols.lift_can`` from the device side (the driver's
module documents the mapping to the model): it receives command frames (0x200 + node), publishes
status frames (0x180 + node) every ``status_period`` and NMT heartbeats (0x700 + node)
every ``heartbeat_period``, preceded by a boot-up heartbeat (0x00) when it starts.

Physics: the carriage moves at ``speed`` mm/s between 0 and ``travel`` mm; the lower
limit switch is on at 0, the upper at ``travel``; it stops at a limit switch, on a stop
command, on a fault, and when no command frame arrived for ``command_timeout`` s (the
lift's own command watchdog).

Runs in a thread of the hub process (the virtual bus is in-process): ``start()``;
``stop()`` makes the device vanish (no more frames, bus closed), ``start()`` again brings
it back on the same channel with its position kept.  Faults for tests: ``set_fault``,
``ignore_commands`` (frames are neither applied nor echoed), ``preoperational``.
"""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Mapping
from typing import Any

import can
import msgspec

from hubs.drivers import lift_can as driver
from hubs.drivers.base import Driver
from hubs.drivers.params import Positive
from hubs.protocols.lift_can import (
    CMD_DOWN,
    CMD_STOP,
    CMD_UP,
    COB_COMMAND,
    COB_HEARTBEAT,
    COB_STATUS,
    COMMAND_TIMEOUT_S,
    DEFAULT_NODE,
    FLAG_FAULT,
    FLAG_LOWER,
    FLAG_MOVING_DOWN,
    FLAG_MOVING_UP,
    FLAG_UPPER,
    NMT_BOOT,
    NMT_OPERATIONAL,
    NMT_PREOP,
    STATUS_FORMAT,
)
from hubs.sim.registry import InHubSimulator, SimulatedDevice, SimulatorPlugin


class LiftSim:
    def __init__(
        self,
        channel: str,
        node_id: int = DEFAULT_NODE,
        *,
        travel: float = 800.0,
        speed: float = 400.0,
        position: float = 0.0,
        status_period: float = 0.02,
        heartbeat_period: float = 0.1,
        command_timeout: float = COMMAND_TIMEOUT_S,
    ) -> None:
        self.channel = channel
        self.node_id = node_id
        self.travel = travel
        self.speed = speed
        self.position = position
        self.status_period = status_period
        self.heartbeat_period = heartbeat_period
        self.command_timeout = command_timeout
        self.direction = 0  # +1 up, -1 down, 0 stopped
        self.fault_code = 0
        self.ignore_commands = False
        self.preoperational = False
        self.last_command = CMD_STOP
        self.last_seq = 0
        self.commands_received = 0
        self._last_command_time = 0.0
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    # -- control (tests, the hub in sim mode) -------------------------------------------

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> None:
        if self.running:
            return
        self._stop.clear()
        ready = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(ready,), name=f"lift-sim-{self.channel}", daemon=True)
        self._thread.start()
        ready.wait(2.0)

    def stop(self) -> None:
        """The device vanishes (power off, cable pulled)."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None:
            thread.join(2.0)
        with self._lock:
            self.direction = 0

    def set_fault(self, code: int) -> None:
        with self._lock:
            self.fault_code = code
            if code:
                self.direction = 0

    @property
    def upper(self) -> bool:
        return self.position >= self.travel

    @property
    def lower(self) -> bool:
        return self.position <= 0.0

    # -- the device ---------------------------------------------------------------------

    def _apply(self, msg: can.Message) -> None:
        if msg.arbitration_id != COB_COMMAND + self.node_id or msg.dlc < 2:
            return
        if self.ignore_commands or self.preoperational:
            return
        command, seq = msg.data[0], msg.data[1]
        with self._lock:
            self.commands_received += 1
            self.last_command, self.last_seq = command, seq
            self._last_command_time = time.monotonic()
            if self.fault_code:
                self.direction = 0
            elif command == CMD_UP:
                self.direction = 0 if self.upper else 1
            elif command == CMD_DOWN:
                self.direction = 0 if self.lower else -1
            else:
                self.direction = 0

    def _integrate(self, dt: float) -> None:
        with self._lock:
            if self.direction and time.monotonic() - self._last_command_time > self.command_timeout:
                self.direction = 0  # command watchdog
            self.position = min(self.travel, max(0.0, self.position + self.direction * self.speed * dt))
            if (self.direction > 0 and self.upper) or (self.direction < 0 and self.lower):
                self.direction = 0

    def _status_frame(self) -> can.Message:
        with self._lock:
            flags = (
                (FLAG_UPPER if self.upper else 0)
                | (FLAG_LOWER if self.lower else 0)
                | (FLAG_MOVING_UP if self.direction > 0 else 0)
                | (FLAG_MOVING_DOWN if self.direction < 0 else 0)
                | (FLAG_FAULT if self.fault_code else 0)
            )
            data = struct.pack(
                STATUS_FORMAT, round(self.position), flags, self.fault_code & 0xFF, self.last_command, self.last_seq
            )
        return can.Message(arbitration_id=COB_STATUS + self.node_id, data=data, is_extended_id=False)

    def _heartbeat(self, state: int) -> can.Message:
        return can.Message(arbitration_id=COB_HEARTBEAT + self.node_id, data=[state], is_extended_id=False)

    def _run(self, ready: threading.Event) -> None:
        bus = can.Bus(interface="virtual", channel=self.channel)
        try:
            bus.send(self._heartbeat(NMT_BOOT))
            ready.set()
            last = now = time.monotonic()
            next_status, next_heartbeat = now, now + self.heartbeat_period
            while not self._stop.is_set():
                msg = bus.recv(timeout=0.002)
                if msg is not None:
                    self._apply(msg)
                now = time.monotonic()
                self._integrate(now - last)
                last = now
                if now >= next_status:
                    bus.send(self._status_frame())
                    next_status = max(next_status + self.status_period, now)
                if now >= next_heartbeat:
                    bus.send(self._heartbeat(NMT_PREOP if self.preoperational else NMT_OPERATIONAL))
                    next_heartbeat = max(next_heartbeat + self.heartbeat_period, now)
        finally:
            bus.shutdown()


_SIMS: dict[tuple[str, int], LiftSim] = {}
_SIMS_LOCK = threading.Lock()


def ensure_lift(channel: str, node_id: int = DEFAULT_NODE, **kwargs: float) -> LiftSim:
    """The running simulated lift on ``channel`` (started with ``kwargs`` on first use)."""
    with _SIMS_LOCK:
        sim = _SIMS.get((channel, node_id))
        if sim is None:
            sim = _SIMS[(channel, node_id)] = LiftSim(channel, node_id, **kwargs)
    sim.start()
    return sim


# --- as a simulator plugin (device type lift): python-can `virtual` connects one process's buses ----

class LiftSimParams(driver.LiftParams, frozen=True, kw_only=True):
    """The driver's parameters, plus the simulated lift's."""

    sim_speed: Positive = 400.0  # mm/s
    sim_travel: Positive = 800.0  # mm between the limit switches


def _build(resource: str, params: LiftSimParams) -> Driver:
    ensure_lift(params.channel, params.node_id, speed=params.sim_speed, travel=params.sim_travel)
    return driver.build(resource, msgspec.structs.replace(params, interface="virtual"))


def _world(device: SimulatedDevice) -> Mapping[str, Any]:
    return {"sim_speed": 400.0 * device.speed}


PLUGIN = SimulatorPlugin("CAN lift on a virtual bus", in_hub=InHubSimulator(LiftSimParams, _build, _world),
                         defaults={"channel": "statehub-lift"})
