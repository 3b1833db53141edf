"""A Modbus TCP remote-I/O coupler with an RSP tool changer and a three-slot tool dock wired to it.

A real pymodbus TCP server (``pymodbus.simulator`` ``SimDevice`` with separate coil,
discrete-input, holding- and input-register blocks, bit addressing) whose access hook
runs the physics lazily from the clock on every request.  Runs in-process (asyncio,
``ToolChangerServer``) or as a process::

    python -m hubs.sim.toolchanger_modbus --host 127.0.0.1 --port 5020 [--stroke-time S]

(``--port 0`` picks a free port; the first line printed is ``listening on HOST:PORT``.)

The coupler's I/O map is ``hubs.protocols.coupler`` (coils 0-1 lock/unlock solenoid,
discrete inputs 0-5 tool changer, 8-10 dock slots, unit id 1). The simulator adds a side
channel for a robot simulator, the simulated cell (``hubs.sim.cell``) and tests:

=========  ====  =============================================================
table      addr  signal
=========  ====  =============================================================
holding    0     robot flange position, 0 = away, n = at dock slot n
holding    1     air supply on (1) / off (0)
holding    2     tools the operator takes by hand (bit n-1: the tool of slot n)
=========  ====  =============================================================

Physics: the piston moves only with air pressure, toward *locked* while only the lock
solenoid is on and toward *unlocked* while only the unlock solenoid is on (both or
neither: the valve holds), taking ``stroke_time`` s per stroke.  Locking at dock slot
*n* while tool *n* sits there couples the tool; unlocking at its own slot leaves it in
the dock; unlocking away from the dock drops it (it is then neither on the robot nor
home).  A tool coupled at slot *n* stays "home" until the flange leaves the slot.

Faults for tests: ``stuck_coils`` (an output that does not follow its command),
``module_error`` (every request answered with exception 4, device failure),
``stop()``/``start()`` (the coupler vanishes and returns on the same port).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from hubs.protocols.coupler import (
    COIL_LOCK,
    COIL_UNLOCK,
    DEVICE_ID,
    DI_CODE0,
    DI_CODE1,
    DI_DOCK,
    DI_LOCKED,
    DI_PRESENT,
    DI_PRESSURE,
    DI_UNLOCKED,
    TOOLS,
)
from hubs.sim.registry import SimServer, SimulatedDevice, SimulatorPlugin, python_module, tcp_params

DEFAULT_PORT = 5020  # the simulator's when run alone (a real coupler listens on 502)
HR_FLANGE, HR_AIR, HR_HAND = 0, 1, 2
N_BITS = 32  # two 16-bit words per bit table
FC_READ_COILS, FC_WRITE_COIL, FC_WRITE_COILS = 1, 5, 15
FC_READ_DI = 2
FC_HOLDING = (3, 6, 16, 22, 23)

Clock = Callable[[], float]


def _pack(bits: list[bool]) -> list[int]:
    """Bits (bit 0 first) → 16-bit words, the layout pymodbus' bit blocks use."""
    words = []
    for start in range(0, len(bits), 16):
        word = 0
        for i, bit in enumerate(bits[start : start + 16]):
            word |= int(bit) << i
        words.append(word)
    return words


def _unpack(words: list[int], n: int) -> list[bool]:
    return [bool(words[i // 16] >> (i % 16) & 1) for i in range(n)]


@dataclass
class ToolChangerPhysics:
    """Tool changer, air supply and dock; evaluated lazily (``update``) from the clock."""

    stroke_time: float = 0.15
    clock: Clock = time.monotonic
    coils: list[bool] = field(default_factory=lambda: [False] * N_BITS)
    piston: float = 0.0  # 0 unlocked … 1 locked
    pressure: bool = True
    flange_slot: int = 0  # 0 away, 1..3 at dock slot
    attached: str | None = None
    in_dock: dict[str, bool] = field(default_factory=lambda: dict.fromkeys(TOOLS, True))
    hand: set[str] = field(default_factory=set)  # tools the operator wants to hold (holding register 2)
    in_hand: set[str] = field(default_factory=set)  # tools the operator holds
    stuck_coils: dict[int, bool] = field(default_factory=dict)
    module_error: bool = False
    _last: float | None = None

    def __post_init__(self) -> None:
        self._last = self.clock()

    @classmethod
    def holding(cls, tool: str, **kwargs: object) -> ToolChangerPhysics:
        """Start with ``tool`` coupled and locked, away from the dock."""
        sim = cls(**kwargs)  # type: ignore[arg-type]  # the constructor checks the keywords
        sim.attached, sim.piston = tool, 1.0
        sim.in_dock[tool] = False
        sim.coils[COIL_LOCK] = True
        return sim

    def effective_coils(self) -> list[bool]:
        coils = list(self.coils)
        for addr, value in self.stuck_coils.items():
            coils[addr] = value
        return coils

    def update(self) -> None:
        now = self.clock()
        dt = now - (self._last if self._last is not None else now)
        self._last = now
        self._move_piston(dt)
        self._hands()

    def _move_piston(self, dt: float) -> None:
        coils = self.effective_coils()
        lock, unlock = coils[COIL_LOCK], coils[COIL_UNLOCK]
        if not self.pressure or lock == unlock or dt <= 0:
            return
        was_locked = self.piston >= 1.0
        step = dt / self.stroke_time
        self.piston = min(1.0, self.piston + step) if lock else max(0.0, self.piston - step)
        if not was_locked and self.piston >= 1.0 and self.attached is None and 1 <= self.flange_slot <= 3:
            tool = TOOLS[self.flange_slot - 1]
            if self.in_dock[tool]:
                self.attached = tool  # coupled; still physically in the slot until the flange leaves
        if was_locked and self.piston < 1.0 and self.attached is not None:
            tool, self.attached = self.attached, None
            self.in_dock[tool] = self.flange_slot == TOOLS.index(tool) + 1  # else: dropped

    def _hands(self) -> None:
        """The operator takes a wanted tool out of its slot (never one coupled to the robot) and puts it back."""
        for tool in TOOLS:
            if tool in self.hand and tool not in self.in_hand and self.in_dock[tool] and self.attached != tool:
                self.in_dock[tool] = False
                self.in_hand.add(tool)
            elif tool not in self.hand and tool in self.in_hand:
                self.in_hand.discard(tool)
                self.in_dock[tool] = True

    def hand_mask(self) -> int:
        return sum(1 << i for i, tool in enumerate(TOOLS) if tool in self.hand)

    def set_hand(self, mask: int) -> None:
        self.update()
        self.hand = {tool for i, tool in enumerate(TOOLS) if mask >> i & 1}
        self._hands()

    def move_flange(self, slot: int) -> None:
        self.update()
        if (
            self.attached is not None
            and self.flange_slot == TOOLS.index(self.attached) + 1
            and slot != self.flange_slot
        ):
            self.in_dock[self.attached] = False  # the coupled tool leaves the dock with the robot
        if self.attached is not None and slot == TOOLS.index(self.attached) + 1:
            self.in_dock[self.attached] = True  # brought back into its slot
        self.flange_slot = slot

    def discrete_inputs(self) -> list[bool]:
        self.update()
        bits = [False] * N_BITS
        bits[DI_LOCKED] = self.piston >= 1.0
        bits[DI_UNLOCKED] = self.piston <= 0.0
        bits[DI_PRESSURE] = self.pressure
        bits[DI_PRESENT] = self.attached is not None
        code = TOOLS.index(self.attached) + 1 if self.attached is not None else 0
        bits[DI_CODE0], bits[DI_CODE1] = bool(code & 1), bool(code & 2)
        for i, tool in enumerate(TOOLS):
            bits[DI_DOCK + i] = self.in_dock[tool]
        return bits

    def home(self, tool: str) -> bool:
        return self.discrete_inputs()[DI_DOCK + TOOLS.index(tool)]


class ToolChangerServer:
    """The coupler: a pymodbus TCP server around ``ToolChangerPhysics``; stoppable and restartable."""

    def __init__(self, physics: ToolChangerPhysics | None = None, host: str = "127.0.0.1", port: int = 0) -> None:
        self.physics = physics or ToolChangerPhysics()
        self.host = host
        self.port = port
        self.device_id = 1
        self.requests = 0
        self._server: ModbusTcpServer | None = None

    async def _action(
        self,
        function_code: int,
        start_address: int,
        address: int,
        count: int,
        current_registers: list[int],
        set_values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        self.requests += 1
        sim = self.physics
        if sim.module_error:
            return ExcCodes.DEVICE_FAILURE
        if function_code in (FC_WRITE_COIL, FC_WRITE_COILS) and set_values is not None:
            sim.update()
            coils = list(sim.coils)
            for i, value in enumerate(set_values):
                if address + i < N_BITS:
                    coils[address + i] = bool(value)
            sim.coils = coils
            current_registers[:] = _pack(sim.effective_coils())
        elif function_code == FC_READ_COILS:
            current_registers[:] = _pack(sim.effective_coils())
        elif function_code == FC_READ_DI:
            current_registers[:] = _pack(sim.discrete_inputs())
        elif function_code in FC_HOLDING:
            if set_values is not None:
                regs = [sim.flange_slot, int(sim.pressure), sim.hand_mask(), 0]
                for i, value in enumerate(set_values):
                    if address + i < len(regs):
                        regs[address + i] = int(value)
                if not 0 <= regs[HR_FLANGE] <= 3 or not 0 <= regs[HR_HAND] < 1 << len(TOOLS):
                    return ExcCodes.ILLEGAL_VALUE
                sim.update()
                sim.pressure = bool(regs[HR_AIR])
                sim.move_flange(regs[HR_FLANGE])
                sim.set_hand(regs[HR_HAND])
            current_registers[:] = [sim.flange_slot, int(sim.pressure), sim.hand_mask(), 0]
        return None

    def _device(self) -> SimDevice:
        return SimDevice(
            self.device_id,
            simdata=(
                [SimData(0, count=N_BITS // 16, values=0, datatype=DataType.BITS)],
                [SimData(0, count=N_BITS // 16, values=0, datatype=DataType.BITS)],
                [SimData(0, count=4, values=0, datatype=DataType.REGISTERS)],
                [SimData(0, count=4, values=0, datatype=DataType.REGISTERS)],
            ),
            action=self._action,
        )

    async def start(self) -> int:
        """Listen (on the same port again after a ``stop``); returns the port."""
        if self._server is not None:
            return self.port
        server = ModbusTcpServer(self._device(), address=(self.host, self.port))
        await server.serve_forever(background=True)
        self._server = server
        listener = server.transport
        assert isinstance(listener, asyncio.Server)  # what pymodbus keeps as a TCP server's transport
        self.port = listener.sockets[0].getsockname()[1]
        return self.port

    async def stop(self) -> None:
        """The coupler vanishes: open connections are dropped and nothing listens."""
        server, self._server = self._server, None
        if server is not None:
            await server.shutdown()
            await asyncio.sleep(0)

    @property
    def running(self) -> bool:
        return self._server is not None

    async def __aenter__(self) -> ToolChangerServer:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()


async def _serve(host: str, port: int, holding: str | None, stroke_time: float) -> None:
    physics = (ToolChangerPhysics.holding(holding, stroke_time=stroke_time) if holding
               else ToolChangerPhysics(stroke_time=stroke_time))
    server = ToolChangerServer(physics, host, port)
    bound = await server.start()
    print(f"listening on {host}:{bound}", flush=True)
    try:
        await asyncio.Event().wait()
    finally:
        await server.stop()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Simulated Modbus TCP coupler with RSP tool changer and tool dock")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT, help="TCP port (0: any free port)")
    parser.add_argument("--holding", choices=TOOLS, help="start with this tool coupled and locked")
    parser.add_argument("--stroke-time", type=float, default=0.15, help="s per piston stroke (0.15)")
    args = parser.parse_args(argv)
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(_serve(args.host, args.port, args.holding, args.stroke_time))
    return 0


# --- as a simulator plugin (device types rsp and dock) -------------------------------------------

def _coupler(device: SimulatedDevice) -> SimServer:
    # A dock is wired to its tool changer's coupler: both name the same process.
    changer = device.model.get("changer") if device.device_type == "dock" else None
    return SimServer(
        python_module("hubs.sim.toolchanger_modbus", "--host", "127.0.0.1", "--port", "0",
                      "--stroke-time", f"{max(0.05, 0.15 / device.speed):.4f}"),
        driver_params=lambda address: {**tcp_params(address), "device_id": DEVICE_ID},
        name=f"coupler-{changer or device.resource}")


PLUGIN = SimulatorPlugin("Modbus coupler", server=_coupler, defaults={"host": "127.0.0.1", "port": DEFAULT_PORT})


if __name__ == "__main__":
    sys.exit(main())
