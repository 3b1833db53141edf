"""A simulated I2C bus with a register-level MCP23017 and a nutrunner wired to its pins.

There is no ``/dev/i2c-*`` on a development machine, so the hub in ``sim`` mode hands the
nutrunner driver an in-process bus object with the same methods as ``smbus2.SMBus``
(``read_byte_data``, ``write_byte_data``, ``read_i2c_block_data``,
``write_i2c_block_data``, ``close``).  Everything below the bus is modelled at the
register level, so the driver's real protocol code runs unchanged.

MCP23017 model (datasheet DS20001952):

* 22 registers; IOCON.BANK selects the address map (BANK=0: A/B registers paired,
  ``IODIRA=0x00 … OLATB=0x15``; BANK=1: port A at 0x00-0x0A, port B at 0x10-0x1A).
* IOCON.SEQOP=0 (sequential): the address pointer increments after each byte of a block
  transfer and wraps (BANK=0: 0x15 → 0x00; BANK=1: within the port's block).
  SEQOP=1 (byte mode): BANK=0 toggles between the A/B pair, BANK=1 stays.
* GPIO reads the pin levels: an output pin (IODIR bit 0) reads its OLAT bit (unless the
  pin is shorted, see ``short``), an input pin reads the level the wired device drives,
  or 1 with GPPU pull-up and nothing driving, XOR IPOL.  A GPIO write writes OLAT.
* Power-on reset: IODIR = 0xFF, everything else 0.
* A device that is not on the bus (``vanish``) makes every transfer raise
  ``OSError(121, 'Remote I/O error')``, as the Linux i2c-dev driver does on a NACK.

Nutrunner wired to the expander (defaults match the driver's defaults):
``GPA0`` → tool *run* input; tool outputs *running* → ``GPB0``, *torque reached (OK)* →
``GPB1``, *fail (NOK)* → ``GPB2``.  After *run* goes high the spindle spins up
(``spinup`` s, then running), tightens (``tighten`` s) and then reports torque reached,
or fail with probability ``fail_probability`` (seeded).  When *run* goes low it resets
all its outputs after ``reset`` s, like the tool does.  Physics is evaluated lazily from
the clock on every bus transfer, so no thread is needed and tests are deterministic.
"""

from __future__ import annotations

import dataclasses
import errno
import os
import random
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, TypeVar

import msgspec

from hubs.drivers import nutrunner_mcp23017 as driver
from hubs.drivers.base import Driver
from hubs.drivers.params import NonNegative
from hubs.protocols.mcp23017 import (
    GPIOA,
    GPIOB,
    GPPUA,
    INTCAPA,
    INTCAPB,
    INTFA,
    INTFB,
    IOCON,
    IOCON_ALT,
    IOCON_BANK,
    IOCON_SEQOP,
    IODIRA,
    IODIRB,
    IPOLA,
    NREG,
    OLATA,
)
from hubs.sim.registry import InHubSimulator, SimulatedDevice, SimulatorPlugin

Clock = Callable[[], float]


def remote_io_error() -> OSError:
    return OSError(errno.EREMOTEIO, os.strerror(errno.EREMOTEIO))


class Mcp23017Sim:
    """Register-level MCP23017. ``pin_source(port, bit)`` gives the level an external device drives, or None."""

    def __init__(self, pin_source: Callable[[int, int], bool | None] | None = None) -> None:
        self.regs = bytearray(NREG)
        self.pin_source = pin_source or (lambda port, bit: None)
        self.shorts: dict[tuple[int, int], bool] = {}  # (port, bit) -> forced pin level
        self.ignore_writes = False  # a device at the address that acknowledges but does not store
        self._pointer = 0
        self.power_on_reset()

    # -- state --------------------------------------------------------------------

    def power_on_reset(self) -> None:
        self.regs[:] = bytes(NREG)
        self.regs[IODIRA] = self.regs[IODIRB] = 0xFF
        self._pointer = 0

    @property
    def bank(self) -> int:
        return 1 if self.regs[IOCON] & IOCON_BANK else 0

    def short(self, port: int, bit: int, level: bool | None) -> None:
        """Force a pin's level (a wiring fault); None removes the short."""
        if level is None:
            self.shorts.pop((port, bit), None)
        else:
            self.shorts[(port, bit)] = level

    def output_level(self, port: int, bit: int) -> bool | None:
        """The level the expander drives on a pin, None when the pin is an input (high impedance)."""
        if (port, bit) in self.shorts:
            return self.shorts[(port, bit)]
        if self.regs[IODIRA + port] >> bit & 1:
            return None
        return bool(self.regs[OLATA + port] >> bit & 1)

    def pin_level(self, port: int, bit: int) -> bool:
        if (port, bit) in self.shorts:
            return self.shorts[(port, bit)]
        if not self.regs[IODIRA + port] >> bit & 1:
            return bool(self.regs[OLATA + port] >> bit & 1)
        driven = self.pin_source(port, bit)
        if driven is None:
            return bool(self.regs[GPPUA + port] >> bit & 1)
        return driven

    def gpio(self, port: int) -> int:
        value = 0
        for bit in range(8):
            level = self.pin_level(port, bit)
            is_input = self.regs[IODIRA + port] >> bit & 1
            if is_input and self.regs[IPOLA + port] >> bit & 1:
                level = not level
            value |= int(level) << bit
        return value

    # -- addressing -----------------------------------------------------------------

    def _to_bank0(self, address: int) -> int | None:
        """Register index (BANK=0 numbering) for an address in the current bank mode."""
        if self.bank == 0:
            return address if address < NREG else None
        port, index = address >> 4, address & 0x0F
        if port > 1 or index > 0x0A:
            return None
        return index * 2 + port

    def _next(self, address: int) -> int:
        seqop_byte_mode = bool(self.regs[IOCON] & IOCON_SEQOP)
        if self.bank == 0:
            if seqop_byte_mode:
                return address ^ 1
            return (address + 1) % NREG
        if seqop_byte_mode:
            return address
        base, index = address & 0xF0, address & 0x0F
        return base | ((index + 1) % 0x0B)

    def read(self, address: int) -> int:
        index = self._to_bank0(address)
        if index is None:
            return 0
        if index in (GPIOA, GPIOB):
            return self.gpio(index - GPIOA)
        if index == IOCON_ALT:
            return self.regs[IOCON]
        return self.regs[index]

    def write(self, address: int, value: int) -> None:
        index = self._to_bank0(address)
        if index is None or self.ignore_writes:
            return
        value &= 0xFF
        if index in (GPIOA, GPIOB):
            index += OLATA - GPIOA
        if index in (IOCON, IOCON_ALT):
            self.regs[IOCON] = value & 0xFE  # bit 0 unimplemented
            return
        if index in (INTFA, INTFB, INTCAPA, INTCAPB):
            return  # read-only
        self.regs[index] = value

    def read_block(self, address: int, length: int) -> list[int]:
        out = []
        for _ in range(length):
            out.append(self.read(address))
            address = self._next(address)
        return out

    def write_block(self, address: int, data: Sequence[int]) -> None:
        for value in data:
            self.write(address, value)
            address = self._next(address)


@dataclass
class NutrunnerTiming:
    spinup: float = 0.05
    tighten: float = 0.25
    reset: float = 0.02


class NutrunnerSim:
    """The tool: run input → running, then torque reached or fail; reset when run drops."""

    IDLE, STARTING, TIGHTENING, DONE, RESETTING = "idle", "starting", "tightening", "done", "resetting"

    def __init__(self, timing: NutrunnerTiming | None = None, fail_probability: float = 0.0, seed: int = 0) -> None:
        self.timing = timing or NutrunnerTiming()
        self.fail_probability = fail_probability
        self.rng = random.Random(seed)
        self.state = self.IDLE
        self.since = 0.0
        self.running = self.torque_ok = self.failed = False
        self._will_fail = False
        self.cycles = 0  # completed tightenings (torque reached or failed)

    def update(self, now: float, run: bool) -> None:
        t = self.timing
        while True:
            if self.state == self.IDLE:
                if not run:
                    return
                self.state, self.since = self.STARTING, now
            elif self.state in (self.STARTING, self.TIGHTENING, self.DONE) and not run:
                self.state, self.since = self.RESETTING, now
            elif self.state == self.STARTING:
                if now - self.since < t.spinup:
                    return
                self.since += t.spinup
                self.state, self.running = self.TIGHTENING, True
                self._will_fail = self.rng.random() < self.fail_probability
            elif self.state == self.TIGHTENING:
                if now - self.since < t.tighten:
                    return
                self.since += t.tighten
                self.state = self.DONE
                self.cycles += 1
                if self._will_fail:
                    self.failed = True
                else:
                    self.torque_ok = True
            elif self.state == self.DONE:
                return
            elif self.state == self.RESETTING:
                if now - self.since < t.reset:
                    return
                self.running = self.torque_ok = self.failed = False
                self.state, self.since = self.IDLE, now
                if not run:
                    return


@dataclass(frozen=True)
class Wiring:
    """Expander pins as (port, bit), port 0 = A, 1 = B."""

    run: tuple[int, int] = (0, 0)
    running: tuple[int, int] = (1, 0)
    torque_ok: tuple[int, int] = (1, 1)
    fail: tuple[int, int] = (1, 2)


class NutrunnerStation:
    """An MCP23017 with a nutrunner wired to it: what sits at one I2C address."""

    def __init__(
        self,
        *,
        wiring: Wiring | None = None,
        timing: NutrunnerTiming | None = None,
        fail_probability: float = 0.0,
        seed: int = 0,
        clock: Clock = time.monotonic,
        trace: str = "",
    ) -> None:
        self.wiring = wiring or Wiring()
        self.clock = clock
        self.trace = trace  # a file that gets a line `<unix time> <run level>` at each change of the run output
        self._traced: bool | None = None
        self.tool = NutrunnerSim(timing, fail_probability, seed)
        self.chip = Mcp23017Sim(self._drive)

    def _drive(self, port: int, bit: int) -> bool | None:
        w = self.wiring
        pin = (port, bit)
        if pin == w.running:
            return self.tool.running
        if pin == w.torque_ok:
            return self.tool.torque_ok
        if pin == w.fail:
            return self.tool.failed
        return None

    def tick(self) -> None:
        level = self.chip.output_level(*self.wiring.run)
        self.tool.update(self.clock(), bool(level))  # an unconfigured (input) pin does not run the tool
        if self.trace and bool(level) != self._traced:
            self._traced = bool(level)
            # Outlives the hub's process: what a test reads after SIGTERM (the output as the tool saw it).
            with open(self.trace, "a", encoding="ascii") as file:
                file.write(f"{time.time():.6f} {int(bool(level))}\n")


Result = TypeVar("Result")  # what a transfer returns


class SimI2CBus:
    """An I2C bus segment with simulated devices; thread-safe (the driver calls from a worker thread)."""

    def __init__(self) -> None:
        self.devices: dict[int, NutrunnerStation] = {}
        self.absent: set[int] = set()
        self.lock = threading.Lock()
        self.transfers = 0

    def add(self, address: int, device: NutrunnerStation) -> NutrunnerStation:
        with self.lock:
            self.devices[address] = device
        return device

    def vanish(self, address: int) -> None:
        """The device stops answering (cable pulled, power lost)."""
        with self.lock:
            self.absent.add(address)

    def restore(self, address: int, *, power_cycled: bool = True) -> None:
        """The device answers again; after a power cycle its registers are at their reset values."""
        with self.lock:
            self.absent.discard(address)
            if power_cycled and address in self.devices:
                self.devices[address].chip.power_on_reset()

    def open(self) -> SimBusHandle:
        return SimBusHandle(self)

    def _device(self, address: int) -> NutrunnerStation:
        device = self.devices.get(address)
        if device is None or address in self.absent:
            raise remote_io_error()
        self.transfers += 1
        device.tick()
        return device

    def transfer(self, address: int, fn: Callable[[Mcp23017Sim], Result]) -> Result:
        with self.lock:
            device = self._device(address)
            result = fn(device.chip)
            device.tick()
            return result


class SimBusHandle:
    """One opened bus, with the ``smbus2.SMBus`` methods the driver uses."""

    def __init__(self, bus: SimI2CBus) -> None:
        self._bus = bus
        self._closed = False

    def _check(self) -> SimI2CBus:
        if self._closed:
            raise OSError(errno.EBADF, "bus closed")
        return self._bus

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        return self._check().transfer(i2c_addr, lambda chip: chip.read_block(register, 1)[0])

    def write_byte_data(self, i2c_addr: int, register: int, value: int, force: bool | None = None) -> None:
        self._check().transfer(i2c_addr, lambda chip: chip.write_block(register, [value]))

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int, force: bool | None = None) -> list[int]:
        if not 0 < length <= 32:
            raise ValueError("Desired block length over 32 bytes")
        return self._check().transfer(i2c_addr, lambda chip: chip.read_block(register, length))

    def write_i2c_block_data(
        self, i2c_addr: int, register: int, data: Sequence[int], force: bool | None = None
    ) -> None:
        if len(data) > 32:
            raise ValueError("Data length cannot exceed 32 bytes")
        self._check().transfer(i2c_addr, lambda chip: chip.write_block(register, data))

    def close(self) -> None:
        self._closed = True


# -- the process-wide simulated buses the hub uses in sim mode ----------------------------

_BUSES: dict[int, SimI2CBus] = {}
_BUSES_LOCK = threading.Lock()


def sim_bus(number: int) -> SimI2CBus:
    """The simulated bus ``/dev/i2c-<number>`` of this process (created on first use)."""
    with _BUSES_LOCK:
        return _BUSES.setdefault(number, SimI2CBus())


def ensure_nutrunner(bus_number: int, address: int,
                     build: Callable[[], NutrunnerStation] = NutrunnerStation) -> NutrunnerStation:
    """The nutrunner station at ``address`` on the simulated bus, made by ``build`` if absent."""
    bus = sim_bus(bus_number)
    with bus.lock:
        existing = bus.devices.get(address)
    if existing is not None:
        return existing
    return bus.add(address, build())


# --- as a simulator plugin (device type nutrunner): inside the hub, there is no /dev/i2c here ------

class NutrunnerSimParams(driver.NutrunnerParams, frozen=True, kw_only=True):
    """The driver's parameters, plus the simulated tool's."""

    sim_fail_probability: Annotated[float, msgspec.Meta(ge=0, le=1)] = 0.0
    sim_seed: int = 0
    sim_spinup: NonNegative = 0.05
    sim_tighten: NonNegative = 0.25
    sim_reset: NonNegative = 0.02
    sim_trace: str = ""  # file traced with every change of the run output (tests)


def _build(resource: str, params: NutrunnerSimParams) -> Driver:
    ensure_nutrunner(params.bus, params.address, lambda: NutrunnerStation(
        wiring=Wiring(**dataclasses.asdict(params.pins())),
        timing=NutrunnerTiming(params.sim_spinup, params.sim_tighten, params.sim_reset),
        fail_probability=params.sim_fail_probability, seed=params.sim_seed, trace=params.sim_trace))
    return driver.build(resource, params, bus_factory=sim_bus(params.bus).open)


def _world(device: SimulatedDevice) -> Mapping[str, Any]:
    timing = NutrunnerTiming()
    return {"sim_seed": device.seed, "sim_fail_probability": device.failure_probability,
            "sim_spinup": timing.spinup / device.speed, "sim_tighten": timing.tighten / device.speed,
            "sim_reset": timing.reset / device.speed}


PLUGIN = SimulatorPlugin("MCP23017 and nutrunner on a simulated I2C bus",
                         in_hub=InHubSimulator(NutrunnerSimParams, _build, _world))
