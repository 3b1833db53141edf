"""The vacuum ejector's protocol simulator: a Modbus TCP server that behaves like the ejector on its gateway.

Run it as a process (what `hubctl up --mode sim` starts, through `PLUGIN`, the
`statehub.simulators` entry point of this package)::

    python -m pick_cell.sim --host 127.0.0.1 --port 0 [--speed S]

(`--port 0` picks a free port; the first line printed is `listening on HOST:PORT`.) Or
in-process, in a test: `async with EjectorServer() as server: ... server.port`.

The I/O map, unit (device id) 1, as `pick_cell.driver` reads it:

=========  ====  =============================================================
table      addr  signal
=========  ====  =============================================================
coil       0     suction valve (the venturi gets compressed air)
coil       1     blow-off valve; the ejector closes it by itself after its blow-off time
discrete   0     switch point 1: vacuum above the hold threshold (600 mbar, off below 550)
discrete   1     supply pressure OK
holding    0     SIMULATOR ONLY: compressed-air supply on (1) / off (0)
=========  ====  =============================================================

Physics, lazily from the clock on every request: with supply pressure and the suction
valve open the vacuum rises to 850 mbar in `evacuation_time`; with the valve closed it
leaks back to ambient in `release_time`, five times faster while blowing off. The cup
always seals (the simulator has no box sensor): the cell switches suction on only over a box.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from hubs.sim import registry

COIL_SUCTION, COIL_BLOW_OFF = 0, 1
DI_VACUUM_OK, DI_SUPPLY_OK = 0, 1
HR_SUPPLY = 0
FULL_VACUUM_MBAR = 850.0
HOLD_ON_MBAR, HOLD_OFF_MBAR = 600.0, 550.0
BLOW_OFF_SPEEDUP = 5.0
FC_READ_COILS, FC_READ_DI, FC_WRITE_COIL, FC_WRITE_COILS = 1, 2, 5, 15
FC_HOLDING = (3, 6, 16, 22, 23)
BITS = 16  # one 16-bit word per bit table


@dataclass
class EjectorPhysics:
    evacuation_time: float = 0.25  # s from ambient to full vacuum
    release_time: float = 0.6  # s from full vacuum back to ambient without blow-off
    blow_off_time: float = 0.1  # s the blow-off pulse lasts
    clock: Callable[[], float] = time.monotonic
    suction: bool = False
    blow_off_until: float = 0.0
    supply: bool = True
    vacuum_mbar: float = 0.0
    holding: bool = False  # switch point 1, with its hysteresis
    _last: float = field(default=0.0, init=False)

    def __post_init__(self) -> None:
        self._last = self.clock()

    @property
    def blowing_off(self) -> bool:
        return self.clock() < self.blow_off_until

    def update(self) -> None:
        now = self.clock()
        last, self._last = self._last, now
        dt = max(0.0, now - last)
        if self.suction and self.supply:
            self.vacuum_mbar = min(FULL_VACUUM_MBAR, self.vacuum_mbar + dt * FULL_VACUUM_MBAR / self.evacuation_time)
        else:
            blown = max(0.0, min(now, self.blow_off_until) - last)  # the part of dt the blow-off pulse lasted
            drop = (dt + blown * (BLOW_OFF_SPEEDUP - 1.0)) * FULL_VACUUM_MBAR / self.release_time
            self.vacuum_mbar = max(0.0, self.vacuum_mbar - drop)
        threshold = HOLD_OFF_MBAR if self.holding else HOLD_ON_MBAR
        self.holding = self.vacuum_mbar >= threshold

    def set_valves(self, suction: bool, blow_off: bool) -> None:
        self.update()
        if blow_off and not self.blowing_off:
            self.blow_off_until = self.clock() + self.blow_off_time
        elif not blow_off:
            self.blow_off_until = 0.0
        self.suction = suction

    def coils(self) -> list[bool]:
        bits = [False] * BITS
        bits[COIL_SUCTION], bits[COIL_BLOW_OFF] = self.suction, self.blowing_off
        return bits

    def discrete_inputs(self) -> list[bool]:
        self.update()
        bits = [False] * BITS
        bits[DI_VACUUM_OK], bits[DI_SUPPLY_OK] = self.holding, self.supply
        return bits


def _word(bits: list[bool]) -> list[int]:
    return [sum(int(bit) << i for i, bit in enumerate(bits))]


class EjectorServer:
    """The ejector's gateway: a pymodbus TCP server around `EjectorPhysics`."""

    def __init__(self, physics: EjectorPhysics | None = None, host: str = "127.0.0.1", port: int = 0) -> None:
        self.physics = physics or EjectorPhysics()
        self.host, self.port = host, port
        self._server: ModbusTcpServer | None = None

    async def _action(self, function_code: int, start_address: int, address: int, count: int,
                      current_registers: list[int], set_values: list[int] | list[bool] | None) -> None:
        physics = self.physics
        if function_code in (FC_WRITE_COIL, FC_WRITE_COILS) and set_values is not None:
            valves = physics.coils()
            for i, value in enumerate(set_values):
                if address + i < BITS:
                    valves[address + i] = bool(value)
            physics.set_valves(valves[COIL_SUCTION], valves[COIL_BLOW_OFF])
            current_registers[:] = _word(physics.coils())
        elif function_code == FC_READ_COILS:
            current_registers[:] = _word(physics.coils())
        elif function_code == FC_READ_DI:
            current_registers[:] = _word(physics.discrete_inputs())
        elif function_code in FC_HOLDING:
            if set_values is not None and address == HR_SUPPLY and set_values:
                physics.update()
                physics.supply = bool(set_values[0])
            current_registers[:] = [int(physics.supply)]

    def _device(self) -> SimDevice:
        def block(datatype: DataType) -> list[SimData]:
            return [SimData(0, count=1, values=0, datatype=datatype)]

        blocks = (block(DataType.BITS), block(DataType.BITS), block(DataType.REGISTERS), block(DataType.REGISTERS))
        return SimDevice(1, simdata=blocks, action=self._action)

    async def start(self) -> int:
        """Listen; returns the port."""
        if self._server is None:
            self._server = ModbusTcpServer(self._device(), address=(self.host, self.port))
            await self._server.serve_forever(background=True)
            listener = self._server.transport
            assert isinstance(listener, asyncio.Server)  # what pymodbus keeps as a TCP server's transport
            self.port = listener.sockets[0].getsockname()[1]
        return self.port

    async def stop(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            await server.shutdown()

    async def __aenter__(self) -> EjectorServer:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()


# --- the simulator plugin: how `hubctl up --mode sim` starts one for a device --------------------

DEFAULT_PORT = 5030


def _server(device: registry.SimulatedDevice) -> registry.SimServer:
    def driver_params(address: str) -> Mapping[str, Any]:
        host, port = registry.host_port(address)
        return {"host": host, "port": port, "device_id": 1}

    argv = registry.python_module("pick_cell.sim", "--host", "127.0.0.1", "--port", "0", "--speed", f"{device.speed:g}")
    return registry.SimServer(argv=argv, driver_params=driver_params, name=f"ejector-{device.resource}")


PLUGIN = registry.SimulatorPlugin(what="vacuum ejector on a Modbus TCP gateway", server=_server,
                                  defaults={"host": "127.0.0.1", "port": DEFAULT_PORT})


async def _serve(host: str, port: int, speed: float) -> None:
    physics = EjectorPhysics(evacuation_time=0.25 / speed, release_time=0.6 / speed, blow_off_time=0.1 / speed)
    async with EjectorServer(physics, host, port) as server:
        print(f"listening on {host}:{server.port}", flush=True)
        await asyncio.Event().wait()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Simulated vacuum ejector on a Modbus TCP gateway (pick_cell)")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT, help="TCP port (0: any free port)")
    parser.add_argument("--speed", type=float, default=1.0, help="simulated time runs this much faster")
    args = parser.parse_args(argv)
    if args.speed <= 0:
        parser.error(f"--speed must be positive, got {args.speed}")
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(_serve(args.host, args.port, args.speed))
    return 0


if __name__ == "__main__":
    sys.exit(main())
