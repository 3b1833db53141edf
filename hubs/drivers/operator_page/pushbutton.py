"""A GPIO pushbutton read through an MCP23017 port expander: a second input for the operator's confirm.

The button is wired between an expander input and ground, with the expander's pull-up enabled
(`active_low`, the default) or to the supply with an external pull-down. The expander is polled (the
same smbus2 bus and register map as the nutrunner's driver, hubs/drivers/nutrunner_mcp23017.py) and
every press (the level going to pressed) is reported once; holding it down is one press. A bus error
is logged once per distinct error and the poll goes on: the page still works without its button."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

from hubs.drivers.nutrunner_mcp23017 import BusFactory, I2CBus
from hubs.protocols.mcp23017 import GPIOA, GPPUA, IODIRA

log = logging.getLogger(__name__)


class Pushbutton:
    def __init__(self, bus_factory: BusFactory, address: int, pin: tuple[int, int], *, active_low: bool = True,
                 poll_s: float = 0.02, on_press: Callable[[], None] = lambda: None) -> None:
        self.bus_factory, self.address, self.pin = bus_factory, address, pin
        self.active_low, self.poll_s, self.on_press = active_low, poll_s, on_press
        self.pressed = False
        self.presses = 0
        self.last_error = ""
        self._bus: I2CBus | None = None
        self._task: asyncio.Task[None] | None = None

    @property
    def answering(self) -> bool:
        return self._bus is not None and not self.last_error

    def start(self) -> None:
        if self._task is None:
            self._task = asyncio.create_task(self._poll(), name="pushbutton")

    async def stop(self) -> None:
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
        bus, self._bus = self._bus, None
        if bus is not None:
            await asyncio.to_thread(bus.close)

    def _configure(self) -> I2CBus:
        bus = self.bus_factory()
        port, bit = self.pin
        iodir = bus.read_byte_data(self.address, IODIRA + port)
        bus.write_byte_data(self.address, IODIRA + port, iodir | 1 << bit)  # an input
        if self.active_low:
            pullups = bus.read_byte_data(self.address, GPPUA + port)
            bus.write_byte_data(self.address, GPPUA + port, pullups | 1 << bit)
        return bus

    def _level(self) -> bool:
        if self._bus is None:
            self._bus = self._configure()
        port, bit = self.pin
        high = bool(self._bus.read_byte_data(self.address, GPIOA + port) >> bit & 1)
        return high != self.active_low

    async def _poll(self) -> None:
        while True:
            try:
                pressed = await asyncio.to_thread(self._level)
            except OSError as exc:
                error = f"MCP23017 at 0x{self.address:02x}: {exc}"
                if error != self.last_error:
                    log.warning("pushbutton: %s", error)
                self.last_error, self._bus = error, None  # reconfigured at the next poll (a power cycle)
            else:
                self.last_error = ""
                if pressed and not self.pressed:
                    self.presses += 1
                    self.on_press()
                self.pressed = pressed
            await asyncio.sleep(self.poll_s)
