"""Which simulator stands in for a device type in sim mode: built-in simulators, then plugins.

A `SimulatorPlugin` says how to simulate one device of its type, in one of two ways:

* `server`: a process of its own that speaks the device's protocol (Modbus TCP, REST,
  RTDE, a pty, ...). The sim world (`deploy/local/simworld.py`) starts the process, waits
  for the line it prints once it serves (`SimServer.ready`, group 1 = its address),
  and hands the hub the driver parameters that point the real driver at it
  (`SimServer.driver_params(address)`), through a parameter-override file.
* `in_hub`: a simulator that must live in the hub's process (an I2C bus that does not
  exist on the machine, a python-can `virtual` bus, which only connects buses of one
  process). The hub builds the driver through `InHubSimulator.build`, which starts the
  simulator and wires the driver to it; the sim world only sends its parameters.

`defaults` are the driver parameters of a simulator at its own default address, for a
device configured `mode = "sim"` that runs without the sim world (a simulator started
by hand). A package ships a simulator for its own device type as an entry point::

    [project.entry-points."statehub.simulators"]
    gripper = "my_cell.gripper_sim:PLUGIN"

`hubctl up --mode sim` runs a device in sim mode when its type has a simulator plugin,
and emulated from the model otherwise (the operator, the AGV).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec

from hubs.drivers.base import Driver
from hubs.drivers.params import require_strict
from hubs.plugins import PluginTable

ENTRY_POINT_GROUP = "statehub.simulators"
LISTENING = r"listening on (\S+)"  # what the built-in servers print: `listening on HOST:PORT`


@dataclass(frozen=True)
class SimulatedDevice:
    """One device the sim world simulates: what a simulator plugin is told about it."""

    resource: str
    device_type: str
    params: Mapping[str, Any]  # its parameters in hubs.toml (those of the real device)
    model: Mapping[str, Any]  # the resource's parameters in the station model
    run_dir: Path  # the world's directory: logs, parameter files, pty links
    speed: float = 1.0  # simulated time runs this much faster
    seed: int = 0
    failure_probability: float = 0.0  # of the device's alternative outcome, where it has one


@dataclass(frozen=True)
class SimServer:
    """The simulator process of one device."""

    argv: Sequence[str]
    driver_params: Callable[[str], Mapping[str, Any]]  # its address -> the parameters pointing the driver at it
    ready: str = LISTENING  # regex of the line it prints once it serves; group 1 (if any) is its address
    name: str = ""  # its log's name; devices whose servers have the same name share one process
    control: bool = False  # keep a pipe to its stdin (the world's couplings write lines to it)
    files: tuple[Path, ...] = ()  # removed when the world stops


@dataclass(frozen=True)
class InHubSimulator:
    """A simulator inside the hub process."""

    params: type[msgspec.Struct]  # the driver's parameters plus the simulator's own (forbid_unknown_fields)
    build: Callable[[str, Any], Driver]  # starts the simulator, returns the driver wired to it
    world_params: Callable[[SimulatedDevice], Mapping[str, Any]] = lambda device: {}  # what the sim world sends

    def __post_init__(self) -> None:
        require_strict(self.params)


@dataclass(frozen=True)
class SimulatorPlugin:
    what: str  # what it simulates, for people: "MiR REST API"
    server: Callable[[SimulatedDevice], SimServer] | None = None
    in_hub: InHubSimulator | None = None
    defaults: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if (self.server is None) == (self.in_hub is None):
            raise TypeError(f"simulator plugin {self.what!r}: give exactly one of server and in_hub")


_TABLE: PluginTable[SimulatorPlugin] = PluginTable(ENTRY_POINT_GROUP, SimulatorPlugin, {
    "nutrunner": "hubs.sim.mcp23017:PLUGIN",
    "lift": "hubs.sim.lift_can:PLUGIN",
    "rsp": "hubs.sim.toolchanger_modbus:PLUGIN",
    "dock": "hubs.sim.toolchanger_modbus:PLUGIN",
    "mir": "hubs.sim.mir_rest:PLUGIN",
    "camera": "hubs.sim.camera_tracker:PLUGIN",
    "rfid": "hubs.sim.rfid_serial:PLUGIN",
    "ur": "hubs.sim.ur_rtde_fake:PLUGIN",
})


def find_simulator(device_type: str) -> SimulatorPlugin | None:
    """The simulator of `device_type`: built-in first, then entry points; None when there is none."""
    return _TABLE.find(device_type)


def simulator_types() -> list[str]:
    return _TABLE.names()


# --- for writing simulator plugins ------------------------------------------------------------

def python_module(module: str, *args: str) -> list[str]:
    """The argv running `python -m module args` with this interpreter."""
    return [sys.executable, "-m", module, *args]


def host_port(address: str) -> tuple[str, int]:
    """`127.0.0.1:5020` -> ("127.0.0.1", 5020)."""
    host, _, port = address.rpartition(":")
    return host, int(port)


def tcp_params(address: str) -> dict[str, Any]:
    """`127.0.0.1:5020` -> {"host": "127.0.0.1", "port": 5020}: the parameters of most TCP drivers."""
    host, port = host_port(address)
    return {"host": host, "port": port}
