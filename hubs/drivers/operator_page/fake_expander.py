"""The pushbutton's simulator: a register-level MCP23017 (hubs/sim/mcp23017.py) with a button on one pin,
behind the methods of ``smbus2.SMBus`` the pushbutton uses. Tests press it; `--mode sim` could too."""

from __future__ import annotations

import errno
import os
import threading
from collections.abc import Sequence

from hubs.sim.mcp23017 import Mcp23017Sim


class ButtonOnExpander:
    """An expander at `address` with a pushbutton to ground on `pin` (the pull-up makes it read high)."""

    def __init__(self, address: int = 0x21, pin: tuple[int, int] = (0, 0)) -> None:
        self.address, self.pin = address, pin
        self.held = False
        self.present = True
        self.lock = threading.Lock()
        self.chip = Mcp23017Sim(self._drive)

    def _drive(self, port: int, bit: int) -> bool | None:
        return False if (port, bit) == self.pin and self.held else None  # released: the pull-up's level

    def press(self, held: bool = True) -> None:
        with self.lock:
            self.held = held

    def open(self) -> FakeBus:
        return FakeBus(self)


class FakeBus:
    def __init__(self, device: ButtonOnExpander) -> None:
        self.device = device

    def _chip(self, address: int) -> Mcp23017Sim:
        if address != self.device.address or not self.device.present:
            raise OSError(errno.EREMOTEIO, os.strerror(errno.EREMOTEIO))
        return self.device.chip

    def read_byte_data(self, i2c_addr: int, register: int) -> int:
        with self.device.lock:
            return self._chip(i2c_addr).read_block(register, 1)[0]

    def write_byte_data(self, i2c_addr: int, register: int, value: int) -> None:
        with self.device.lock:
            self._chip(i2c_addr).write_block(register, [value])

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]:
        with self.device.lock:
            return self._chip(i2c_addr).read_block(register, length)

    def write_i2c_block_data(self, i2c_addr: int, register: int, data: Sequence[int]) -> None:
        with self.device.lock:
            self._chip(i2c_addr).write_block(register, data)

    def close(self) -> None:
        return None
