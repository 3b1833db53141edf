"""Nutrunner behind an MCP23017 16-bit I2C port expander (smbus2).

Wiring (defaults; each pin configurable in hubs.toml as ``"A0"`` … ``"B7"``):

=========  =========  ==========================================  ==========
pin        direction  signal                                      variable
=========  =========  ==========================================  ==========
GPA0       output     tool *run* (start tightening while high)    ``run_c``
GPB0       input      tool *running*                              ``run_m``
GPB1       input      tool *torque reached* (OK)                  ``tqr_m``
GPB2       input      tool *fail* (NOK)                           ``fail_m``
=========  =========  ==========================================  ==========

``inputs_active_low = true`` inverts the three inputs in the driver (open-collector
opto outputs with pull-ups); the expander's IPOL registers are left at 0.

Register map (IOCON.BANK = 0, the map this driver configures and uses):
``hubs.protocols.mcp23017``.

Protocol:

* connect: open the bus; write 0x00 to 0x05 (IOCON if the chip is in BANK=1 mode, else
  GPINTENB, unused here) and 0x00 to IOCON 0x0A (BANK=0, sequential addressing), IPOLA/B
  = 0, IODIRA/B with the run pin as the only output; then apply the last commanded
  ``run_c`` if there was one (the command is the reference state: after a power cycle
  of the expander the output is driven again) or adopt the current latch; then read the
  configuration back.  Any difference means "not an MCP23017 behaving as one": connect
  fails and is retried with backoff.
* read: one sequential block read of all 22 registers (0x00-0x15).  IODIR or IOCON not
  as configured means the chip reset (brown-out): device lost, reconfigured on reconnect.
* write: read-modify-write of the output latch (OLATx), then read back OLATx and GPIOx:
  the latch bit and the pin level must both equal the command.
* every transfer runs in a single-worker thread (smbus2 is blocking, and one worker
  serialises the bus) with ``io_timeout``; an ``OSError`` (121 Remote I/O = NACK) or a
  timeout reports the device lost to the shared ReconnectLogic.

Safe state: ``run_c = false`` (the tool stops and resets).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import functools
import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Annotated, Protocol, TypeVar

import msgspec

from common.model import Value
from hubs.drivers.base import DeviceUnavailable, SelftestReport
from hubs.drivers.params import DriverParams, Positive, invalid
from hubs.drivers.reconnect import Backoff, LinkedDriver, ReconnectLogic, describe
from hubs.drivers.registry import DriverPlugin
from hubs.protocols.mcp23017 import DEFAULT_ADDRESS, GPINTENB, GPIOA, IOCON, IODIRA, IPOLA, NREG, OLATA

log = logging.getLogger(__name__)

IOCON_VALUE = 0x00  # BANK=0, MIRROR=0, SEQOP=0 (sequential), DISSLW=0, ODR=0, INTPOL=0

T = TypeVar("T")


class I2CBus(Protocol):
    """The part of ``smbus2.SMBus`` the driver uses (the simulator's bus satisfies it too)."""

    def read_byte_data(self, i2c_addr: int, register: int) -> int: ...
    def write_byte_data(self, i2c_addr: int, register: int, value: int) -> None: ...
    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]: ...
    def write_i2c_block_data(self, i2c_addr: int, register: int, data: Sequence[int]) -> None: ...
    def close(self) -> None: ...


BusFactory = Callable[[], I2CBus]


def parse_pin(text: str) -> tuple[int, int]:
    """``"A0"`` … ``"B7"`` → (port, bit)."""
    text = text.strip().upper()
    if len(text) != 2 or text[0] not in "AB" or text[1] not in "01234567":
        raise ValueError(f"MCP23017 pin must be A0..A7 or B0..B7, got {text!r}")
    return "AB".index(text[0]), int(text[1])


@dataclass(frozen=True)
class Pins:
    run: tuple[int, int] = (0, 0)
    running: tuple[int, int] = (1, 0)
    torque_ok: tuple[int, int] = (1, 1)
    fail: tuple[int, int] = (1, 2)

    def iodir(self) -> tuple[int, int]:
        """IODIRA, IODIRB: all inputs except the run pin."""
        dirs = [0xFF, 0xFF]
        port, bit = self.run
        dirs[port] &= ~(1 << bit) & 0xFF
        return dirs[0], dirs[1]


def default_bus_factory(bus_number: int) -> BusFactory:
    def factory() -> I2CBus:
        import smbus2

        return smbus2.SMBus(bus_number)

    return factory


class NutrunnerMcp23017(LinkedDriver[ReconnectLogic]):
    def __init__(
        self,
        resource: str = "nr",
        *,
        bus_number: int = 1,
        address: int = 0x20,
        bus_factory: BusFactory | None = None,
        pins: Pins | None = None,
        inputs_active_low: bool = False,
        io_timeout: float = 0.5,
        backoff: Backoff | None = None,
    ) -> None:
        self.resource = resource
        self.bus_number = bus_number
        self.address = address
        self.pins = pins or Pins()
        self.inputs_active_low = inputs_active_low
        self.io_timeout = io_timeout
        self._bus_factory = bus_factory or default_bus_factory(bus_number)
        self._bus: I2CBus | None = None
        self._executor: concurrent.futures.ThreadPoolExecutor | None = None
        self._executor_stuck = False
        self._desired_run: bool | None = None  # last commanded run_c, applied again after a reconnect
        # Writes and the self-test's latch write-back take turns: interleaved, the self-test wrote the
        # latch it had read over a stop commanded meanwhile (seen: the tool started again).
        self._command_lock = asyncio.Lock()
        self._iodir = self.pins.iodir()
        self._link = ReconnectLogic(
            f"{resource}@i2c-{bus_number}:0x{address:02x}",
            self._open,
            self._release,
            backoff=backoff,
            connect_timeout=max(2.0, 6 * io_timeout),
        )

    # -- Driver API -------------------------------------------------------------------

    async def close(self) -> None:
        await super().close()
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None

    async def read(self) -> Mapping[str, Value]:
        regs = await self._registers()
        return self._decode(regs)

    async def write(self, commands: Mapping[str, Value]) -> None:
        if "run_c" not in commands:
            return
        run = bool(commands["run_c"])
        async with self._command_lock:
            self._desired_run = run
            if not self.connected:
                raise DeviceUnavailable(f"{self.resource}: expander not connected ({self._link.last_error})")
            await self._set_run(run)

    async def enter_safe_state(self) -> Mapping[str, Value]:
        safe: dict[str, Value] = {"run_c": False}
        await self.write(safe)  # remembered first: driven on reconnect if the expander is away
        return safe

    async def selftest(self) -> SelftestReport:
        report = SelftestReport(self.resource)
        where = f"bus {self.bus_number} address 0x{self.address:02x}"
        if not await self._link.wait_attempt():
            report.add("device answers", False, f"no MCP23017 at {where}: {self._link.last_error}")
            report.add("inputs read", False, "not checked: device absent")
            report.add("outputs read back", False, "not checked: device absent")
            return report
        report.add("device answers", True, f"MCP23017 at {where}")
        try:
            values = await self.read()
            report.add("inputs read", True, ", ".join(f"{k}={v}" for k, v in values.items()))
        except DeviceUnavailable as exc:
            report.add("inputs read", False, str(exc))
            report.add("outputs read back", False, "not checked: inputs unreadable")
            return report
        try:
            # Non-intrusive: write the run latch with its present value and check latch and pin level.
            async with self._command_lock:
                regs = await self._registers()
                port, bit = self.pins.run
                current = bool(regs[OLATA + port] >> bit & 1)
                await self._set_run(current)
            report.add("outputs read back", True, f"run pin {'AB'[port]}{bit} latch and level = {int(current)}")
        except DeviceUnavailable as exc:
            report.add("outputs read back", False, str(exc))
        return report

    # -- protocol ---------------------------------------------------------------------

    def _decode(self, regs: Sequence[int]) -> dict[str, Value]:
        def level(pin: tuple[int, int]) -> bool:
            port, bit = pin
            value = bool(regs[GPIOA + port] >> bit & 1)
            return value != self.inputs_active_low

        return {
            "run_m": level(self.pins.running),
            "tqr_m": level(self.pins.torque_ok),
            "fail_m": level(self.pins.fail),
        }

    async def _registers(self) -> list[int]:
        """All 22 registers in one sequential read; checks the configuration is still there."""
        if not self.connected:
            raise DeviceUnavailable(f"{self.resource}: expander not connected ({self._link.last_error})")
        regs = await self._io(self._read_all)
        if (regs[IODIRA], regs[IODIRA + 1]) != self._iodir or regs[IOCON] != IOCON_VALUE:
            reason = (
                f"expander reset or reconfigured (IODIR={regs[IODIRA]:#04x}/{regs[IODIRA + 1]:#04x}, "
                f"IOCON={regs[IOCON]:#04x})"
            )
            self._link.connection_lost(reason)
            raise DeviceUnavailable(f"{self.resource}: {reason}")
        return regs

    async def _set_run(self, run: bool) -> None:
        port, bit = self.pins.run

        def apply(bus: I2CBus) -> tuple[int, int]:
            latch = bus.read_byte_data(self.address, OLATA + port)
            latch = latch | (1 << bit) if run else latch & ~(1 << bit) & 0xFF
            bus.write_byte_data(self.address, OLATA + port, latch)
            olat, gpio = (
                bus.read_byte_data(self.address, OLATA + port),
                bus.read_byte_data(self.address, GPIOA + port),
            )
            return olat, gpio

        olat, gpio = await self._io(apply)
        latch_bit, pin_bit = bool(olat >> bit & 1), bool(gpio >> bit & 1)
        if latch_bit != run or pin_bit != run:
            raise DeviceUnavailable(
                f"{self.resource}: run output {'AB'[port]}{bit} not read back: wrote {int(run)}, "
                f"latch {int(latch_bit)}, pin level {int(pin_bit)}"
            )

    def _read_all(self, bus: I2CBus) -> list[int]:
        return list(bus.read_i2c_block_data(self.address, IODIRA, NREG))

    # -- connection -------------------------------------------------------------------

    async def _open(self) -> None:
        if self._executor is None or self._executor_stuck:
            if self._executor is not None:
                self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix=f"i2c-{self.resource}")
            self._executor_stuck = False
        self._bus = await self._run_in_thread(self._bus_factory)
        iodir_a, iodir_b = self._iodir
        desired = self._desired_run

        def configure(bus: I2CBus) -> list[int]:
            bus.write_byte_data(self.address, GPINTENB, 0x00)  # = IOCON when the chip is in BANK=1 mode
            bus.write_byte_data(self.address, IOCON, IOCON_VALUE)
            bus.write_i2c_block_data(self.address, IPOLA, [0x00, 0x00])
            if desired is not None:
                port, bit = self.pins.run
                latch = bus.read_byte_data(self.address, OLATA + port)
                latch = latch | (1 << bit) if desired else latch & ~(1 << bit) & 0xFF
                bus.write_byte_data(self.address, OLATA + port, latch)
            bus.write_i2c_block_data(self.address, IODIRA, [iodir_a, iodir_b])
            return self._read_all(bus)

        regs = await self._io(configure, during_connect=True)
        if (regs[IODIRA], regs[IODIRA + 1]) != self._iodir or regs[IOCON] != IOCON_VALUE:
            raise ConnectionError(
                f"configuration not read back: IODIR {regs[IODIRA]:#04x}/{regs[IODIRA + 1]:#04x} "
                f"(wrote {iodir_a:#04x}/{iodir_b:#04x}), IOCON {regs[IOCON]:#04x}"
            )

    async def _release(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            try:
                await self._run_in_thread(bus.close)
            except Exception as exc:
                log.debug("%s: close failed: %s", self.resource, describe(exc))

    async def _run_in_thread(self, fn: Callable[[], T]) -> T:
        assert self._executor is not None
        loop = asyncio.get_running_loop()
        try:
            async with asyncio.timeout(self.io_timeout):
                return await loop.run_in_executor(self._executor, fn)
        except TimeoutError:
            self._executor_stuck = True  # the worker may hang for good: a fresh one on reconnect
            raise

    async def _io(self, fn: Callable[[I2CBus], T], *, during_connect: bool = False) -> T:
        bus = self._bus
        if bus is None or self._executor is None:
            raise DeviceUnavailable(f"{self.resource}: expander not connected")
        try:
            return await self._run_in_thread(functools.partial(fn, bus))
        except (OSError, TimeoutError) as exc:
            reason = "I2C transfer timed out" if isinstance(exc, TimeoutError) else f"I2C error: {describe(exc)}"
            if during_connect:
                raise ConnectionError(reason) from exc
            self._link.connection_lost(reason)
            raise DeviceUnavailable(f"{self.resource}: {reason}") from exc


class NutrunnerParams(DriverParams, frozen=True, kw_only=True):
    bus: Annotated[int, msgspec.Meta(ge=0)] = 1  # /dev/i2c-<bus>
    address: Annotated[int, msgspec.Meta(ge=0x03, le=0x77)] = DEFAULT_ADDRESS
    run_pin: str = "A0"  # MCP23017 pins, A0..B7
    run_m_pin: str = "B0"
    tqr_m_pin: str = "B1"
    fail_m_pin: str = "B2"
    inputs_active_low: bool = False
    io_timeout: Positive = 0.5

    def __post_init__(self) -> None:
        pins = {"run_pin": self.run_pin, "run_m_pin": self.run_m_pin, "tqr_m_pin": self.tqr_m_pin,
                "fail_m_pin": self.fail_m_pin}
        for key, pin in pins.items():
            try:
                parse_pin(pin)
            except ValueError as exc:
                raise invalid(key, str(exc)) from None

    def pins(self) -> Pins:
        return Pins(run=parse_pin(self.run_pin), running=parse_pin(self.run_m_pin),
                    torque_ok=parse_pin(self.tqr_m_pin), fail=parse_pin(self.fail_m_pin))


def build(resource: str, params: NutrunnerParams, bus_factory: BusFactory | None = None) -> NutrunnerMcp23017:
    return NutrunnerMcp23017(
        resource,
        bus_number=params.bus,
        address=params.address,
        bus_factory=bus_factory,
        pins=params.pins(),
        inputs_active_low=params.inputs_active_low,
        io_timeout=params.io_timeout,
        backoff=params.backoff(),
    )


PLUGIN = DriverPlugin(NutrunnerParams, build)
