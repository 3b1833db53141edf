"""The simulated world of `hubctl up --mode sim`: every device simulator the station needs, coupled.

For each device that runs in `sim` mode (`--mode sim`, or `mode = "sim"` in hubs.toml)
the world asks the simulator registry (`hubs.sim.registry`, built-in simulators and
plugins of the entry-point group `statehub.simulators`) how to simulate its type:

* a simulator *server* (Modbus coupler, fake UR controller, MiR REST API, tracker feed,
  RFID reader on a pty, or a plugin's): the world starts the process, waits for the line
  saying it serves, and hands the hub the driver parameters that point the device's
  driver at it. Devices whose servers have the same name share one process (a dock
  wired to its tool changer's coupler);
* a simulator *inside the hub* (nutrunner on a simulated I2C bus, lift on python-can's
  `virtual` bus, which only connects buses of one process): the hub starts it when it
  builds the driver; the world only sends its simulation parameters.

Devices whose type has no simulator (the operator, the AGV) stay emulated. Each hub
receives its devices' simulator addresses and simulation parameters as a
parameter-override file (`hubctl hub --params-file`, `{resource: {parameter: value}}`),
written to the world's run directory. Simulated time follows `--speed`.

The built-in simulators are coupled as the real cell couples the devices (`hubs.sim.cell`):
the tool changer sees the robot's flange at a dock slot, the dock's sensors follow; and,
with the station's bus (`loopback_port`), the camera sees the emulated operator walk
to where the instruction sends them, the operator takes a tool out of the dock by hand
for a hand-held task and badges in at the RFID reader when nobody is verified.

Run it alone (e.g. for `hubctl selftest HUB --mode sim --params-file ...`)::

    python -m deploy.local.simworld [--config hubs.toml] [--run-dir var/sim] [--speed S] [--loopback-port P]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import os
import re
import signal
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec

from common.bus.protocol import Bus
from common.bus.zenoh_bus import ZenohBus
from common.config.hubs_toml import DeviceConfig, StationConfig, load_station
from common.config.modes import DeviceMode
from common.model import Model
from common.plumbing.lifecycle import exit_process
from common.plumbing.tasks import cancel_and_wait
from common.wire.keys import Keys
from common.wire.messages import Codec
from hubs.factory import chosen_mode
from hubs.protocols.coupler import TOOLS
from hubs.protocols.ur import COMMAND_PORT
from hubs.sim import cell
from hubs.sim.registry import SimServer, SimulatedDevice, SimulatorPlugin, find_simulator, host_port
from hubs.sim.rfid_serial import OPERATOR_TAG

from .localcerts import watcher_zenoh_config

log = logging.getLogger("statehub.simworld")

READY_TIMEOUT_S = 20.0
STOP_GRACE_S = 3.0
TASKS_END_S = 10.0  # for the world's tasks to end once cancelled (pymodbus's wait_for may swallow a cancel)


Say = Callable[[str], object]


class SimulatorError(RuntimeError):
    """A simulator did not start; the message names it and quotes its log."""


# --- one simulator process ---------------------------------------------------------------------

@dataclass
class SimProcess:
    name: str  # e.g. "coupler rsp": also the log's name
    what: str  # what it simulates, for people
    argv: list[str]
    log: Path
    ready: str  # regex of the line it prints once it serves; group 1, if any, is its address
    control: bool = False  # keep a pipe to its stdin for `send`
    files: tuple[Path, ...] = ()  # removed when it stops (a pty link)
    process: asyncio.subprocess.Process | None = None
    address: str = ""

    async def start(self, timeout: float = READY_TIMEOUT_S) -> str:
        self.log.parent.mkdir(parents=True, exist_ok=True)
        with self.log.open("wb") as handle:
            self.process = await asyncio.create_subprocess_exec(
                *self.argv, stdin=asyncio.subprocess.PIPE if self.control else asyncio.subprocess.DEVNULL,
                stdout=handle, stderr=asyncio.subprocess.STDOUT, start_new_session=True,
                env={**os.environ, "PYTHONUNBUFFERED": "1"})
        deadline = time.monotonic() + timeout
        pattern = re.compile(self.ready, re.MULTILINE)
        while True:
            match = pattern.search(self.log.read_text(errors="replace"))
            if match:
                self.address = match.group(1) if pattern.groups else match.group(0)
                return self.address
            if self.process.returncode is not None:
                raise SimulatorError(f"{self.what} ({self.name}) exited with code {self.process.returncode} "
                                     f"before it served: {self.tail()}  (log: {self.log})")
            if time.monotonic() > deadline:
                await self.stop()
                raise SimulatorError(f"{self.what} ({self.name}) did not serve within {timeout:.0f} s: "
                                     f"{self.tail()}  (log: {self.log})")
            await asyncio.sleep(0.05)

    def tail(self, lines: int = 3) -> str:
        text = self.log.read_text(errors="replace").strip() if self.log.exists() else ""
        return " | ".join(text.splitlines()[-lines:]) or "no output"

    @property
    def running(self) -> bool:
        return self.process is not None and self.process.returncode is None

    async def send(self, line: str) -> None:
        """One line to the simulator's stdin (its control input)."""
        if not self.running or self.process is None or self.process.stdin is None:
            raise ConnectionError(f"{self.name} is not running")
        self.process.stdin.write(line.encode() + b"\n")
        await self.process.stdin.drain()

    async def stop(self) -> None:
        try:
            await self._end()
        finally:
            for path in self.files:
                with contextlib.suppress(OSError):
                    path.unlink()

    async def _end(self) -> None:
        process = self.process
        if process is None or process.returncode is not None:
            return
        if process.stdin is not None:
            process.stdin.close()
        with contextlib.suppress(ProcessLookupError):
            process.terminate()
        try:
            async with asyncio.timeout(STOP_GRACE_S):
                await process.wait()
        except TimeoutError:
            with contextlib.suppress(ProcessLookupError):
                process.kill()
            await process.wait()


# --- the world ---------------------------------------------------------------------------------

@dataclass
class SimWorld:
    config: StationConfig
    model: Model
    run_dir: Path
    speed: float = 1.0
    seed: int = 0
    failure: Mapping[str, float] = field(default_factory=dict)
    mode: DeviceMode | None = DeviceMode.SIM  # the `--mode` override; None: as in hubs.toml
    real: frozenset[str] = frozenset()  # `--real`: these devices run real, no simulator for them
    loopback_port: int | None = None  # the station's bus: couples the operator to camera, dock and RFID
    say: Say = print
    certs: Path | None = None  # the run's certificate directory when the station is secured (localcerts.py)
    devices: dict[str, DeviceConfig] = field(default_factory=dict)  # resource -> device, sim devices only
    simulators: dict[str, SimulatorPlugin] = field(default_factory=dict)  # resource -> its type's simulator
    emulated: list[str] = field(default_factory=list)  # devices that stay emulated in sim mode: no simulator
    processes: dict[str, SimProcess] = field(default_factory=dict)  # simulator processes by name
    server_of: dict[str, SimProcess] = field(default_factory=dict)  # resource -> its simulator process
    in_hub: list[str] = field(default_factory=list)  # resources simulated inside their hub
    overrides: dict[str, dict[str, Any]] = field(default_factory=dict)  # resource -> parameters
    params_files: dict[str, Path] = field(default_factory=dict)  # hub -> override file
    _tasks: list[asyncio.Task[None]] = field(default_factory=list)
    _bus: Bus | None = None
    _log_handler: logging.Handler | None = None

    def __post_init__(self) -> None:
        for hub in self.config.hubs.values():
            for resource, device in hub.devices.items():
                chosen = chosen_mode(resource, device.type, device.mode, self.mode, self.real)
                if chosen == DeviceMode.SIM:
                    self.devices[resource] = device
                    simulator = find_simulator(device.type)
                    if simulator is not None:
                        self.simulators[resource] = simulator
                elif self.mode == DeviceMode.SIM and chosen == DeviceMode.EMULATE:
                    self.emulated.append(f"{resource} ({device.type})")

    def hub_args(self, hub: str) -> list[str]:
        """The `hubctl hub` arguments that hand `hub` its simulators."""
        path = self.params_files.get(hub)
        return ["--params-file", str(path)] if path is not None else []

    def of_type(self, *types: str) -> dict[str, DeviceConfig]:
        return {r: d for r, d in self.devices.items() if d.type in types}

    # --- lifecycle ---------------------------------------------------------------------------
    async def start(self) -> None:
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self._log_handler = logging.FileHandler(self.run_dir / "simworld.log")
        self._log_handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
        log.addHandler(self._log_handler)
        log.setLevel(logging.INFO)
        try:
            await self._start_simulators()
            self._write_params()
            await self._couple()
        except BaseException:
            await self.stop()
            raise
        for line in self.summary():
            self.say(line)

    async def stop(self) -> None:
        tasks, self._tasks = self._tasks, []
        await cancel_and_wait(tasks, TASKS_END_S, log)
        if self._bus is not None:
            with contextlib.suppress(Exception):
                await self._bus.close()
            self._bus = None
        await asyncio.gather(*(p.stop() for p in self.processes.values()))
        if self._log_handler is not None:
            log.removeHandler(self._log_handler)
            self._log_handler.close()
            self._log_handler = None

    async def __aenter__(self) -> SimWorld:
        await self.start()
        return self

    async def __aexit__(self, *_exc: object) -> None:
        await self.stop()

    def summary(self) -> list[str]:
        lines = [f"sim world: {len(self.processes)} simulator processes, logs and parameter files in {self.run_dir}/"]
        for process in self.processes.values():
            lines.append(f"  {process.what}: {process.address}")
        for resource in self.in_hub:
            lines.append(f"  {resource} ({self.devices[resource].type}): simulated inside hub "
                         f"{self.config.hub_of(resource).name}")
        for resource in sorted(set(self.devices) - set(self.simulators)):
            lines.append(f"  {resource} ({self.devices[resource].type}): no simulator plugin, its hubs.toml "
                         f"parameters must point at a simulator")
        if self.emulated:
            lines.append(f"  emulated (no protocol simulator): {', '.join(self.emulated)}")
        return lines

    # --- starting the simulators -------------------------------------------------------------
    def _set(self, resource: str, params: Mapping[str, Any]) -> None:
        self.overrides.setdefault(resource, {}).update(params)

    def _described(self, resource: str) -> SimulatedDevice:
        device = self.devices[resource]
        model = self.model.resource_by_name.get(resource)
        return SimulatedDevice(resource, device.type, device.params, model.parameters if model else {}, self.run_dir,
                               speed=self.speed, seed=self.seed,
                               failure_probability=float(self.failure.get(resource, 0.0)))

    async def _start_simulators(self) -> None:
        servers: dict[str, tuple[SimServer, str, list[str]]] = {}  # process name -> server, what, resources
        for resource, simulator in self.simulators.items():
            device = self._described(resource)
            if simulator.in_hub is not None:
                self._set(resource, simulator.in_hub.world_params(device))
                self.in_hub.append(resource)
            elif simulator.server is not None:
                server = simulator.server(device)
                name = server.name or f"{device.device_type}-{resource}"
                servers.setdefault(name, (server, simulator.what, []))[2].append(resource)
        await asyncio.gather(*(self._serve(name, *entry) for name, entry in servers.items()))

    async def _serve(self, name: str, server: SimServer, what: str, resources: list[str]) -> None:
        process = SimProcess(name, f"{what} ({', '.join(resources)})", list(server.argv),
                             self.run_dir / f"{name}.log", server.ready, control=server.control, files=server.files)
        self.processes[name] = process
        address = await process.start()
        for resource in resources:
            self.server_of[resource] = process
            self._set(resource, server.driver_params(address))

    def _write_params(self) -> None:
        for hub in self.config.hubs.values():
            mine = {r: self.overrides[r] for r in hub.devices if r in self.overrides}
            if mine:
                path = self.run_dir / f"{hub.name}.params.json"
                path.write_text(json.dumps(mine, indent=2) + "\n", encoding="utf-8")
                self.params_files[hub.name] = path

    # --- coupling the built-in simulators as the cell couples the devices ----------------------
    def _spawn(self, coroutine: Any, name: str) -> None:
        self._tasks.append(asyncio.create_task(coroutine, name=name))

    def _served(self, *types: str) -> list[str]:
        """The resources of these types that have a simulator process."""
        return [r for r in self.of_type(*types) if r in self.server_of]

    def _coupler(self, resource: str, links: dict[str, cell.CouplerLink]) -> cell.CouplerLink:
        process = self.server_of[resource]
        if process.name not in links:
            links[process.name] = cell.CouplerLink(*host_port(process.address))
        return links[process.name]

    async def _couple(self) -> None:
        couplers: dict[str, cell.CouplerLink] = {}  # by process: a changer and its dock share one
        robots = self._served("ur")
        for changer in self._served("rsp"):
            robot = self.model.resource_by_name[changer].parameters.get("robot")
            if robot not in robots:
                continue
            poses = {name: tuple(pose["q"]) for name, pose in self.overrides[str(robot)]["poses"].items()}
            dock_poses = msgspec.convert(self.model.resource_by_name[changer].parameters["dock_poses"], dict[str, str])
            slots = {TOOLS.index(tool) + 1: poses[pose] for tool, pose in dock_poses.items()}
            tolerance = float(self.devices[str(robot)].params.get("joint_tolerance", 0.01))
            flange = cell.FlangeCoupling(cell.RobotLink(self.server_of[str(robot)].address, COMMAND_PORT),
                                         self._coupler(changer, couplers), slots, tolerance)
            self._spawn(flange.run(), f"flange {changer}")
        if self.loopback_port is None:
            return
        zconfig = watcher_zenoh_config(self.config, self.model, self.loopback_port, self.certs)
        self._bus = await ZenohBus(zconfig).open()
        keys = self.config.keys
        for operator in (r.name for r in self.model.resources if r.device_type == "operator"):
            self._couple_operator(operator, keys, couplers)
        for resource in self._served("rfid"):
            badge = cell.BadgeCoupling(self._bus, keys, Codec(self.model.resource_by_name[resource]),
                                       self.server_of[resource].send, OPERATOR_TAG, delay=0.5 / self.speed, retry=3.0)
            self._spawn(badge.run(), f"badge {resource}")

    def _couple_operator(self, operator: str, keys: Keys, couplers: dict[str, cell.CouplerLink]) -> None:
        assert self._bus is not None
        cameras = [r for r in self._served("camera")
                   if self.model.resource_by_name[r].parameters.get("operator") == operator]
        docks = [r for r in self._served("dock")
                 if self.model.resource_by_name[r].parameters.get("operator") == operator]
        if not cameras and not docks:
            return
        walker = cell.Walker(self.overrides[cameras[0]]["zones"], speed=1.4 * self.speed) if cameras else None
        task_zones = (msgspec.convert(self.model.resource_by_name[cameras[0]].parameters["task_zones"], dict[str, str])
                      if cameras else {})
        handheld: dict[str, list[str]] = {}
        for dock in docks:
            parameters = self.model.resource_by_name[dock].parameters
            for tool, tasks in msgspec.convert(parameters.get("handheld_tasks", {}), dict[str, list[str]]).items():
                handheld.setdefault(tool, []).extend(tasks)
        coupling = cell.OperatorCoupling(
            self._bus, keys, Codec(self.model.resource_by_name[operator]), task_zones, walker,
            [self.server_of[c].send for c in cameras], handheld, [self._coupler(d, couplers) for d in docks])
        self._spawn(coupling.run(), f"operator {operator}")


async def start_world(config: StationConfig, model: Model, options: Any, loopback_port: int,
                      say: Say = print, *, certs: Path | None = None) -> SimWorld | None:
    """`hubctl up --mode sim`: the started world, or None after saying why it could not start."""
    world = SimWorld(config, model, Path(options.run_dir) / "sim", speed=options.speed, seed=options.seed,
                     failure=dict(options.failure), mode=options.mode, real=frozenset(options.real),
                     loopback_port=loopback_port, say=say, certs=certs)
    say(f"starting the sim world in {world.run_dir}/ ...")
    try:
        await world.start()
    except (SimulatorError, ValueError, OSError) as exc:
        say(f"hubctl up: the sim world did not start: {exc}")
        return None
    return world


# --- alone -------------------------------------------------------------------------------------

async def _serve(args: argparse.Namespace) -> int:
    config, model = load_station(args.config)
    world = SimWorld(config, model, Path(args.run_dir), speed=args.speed, seed=args.seed,
                     loopback_port=args.loopback_port)
    try:
        await world.start()
    except SimulatorError as exc:
        print(f"simworld: {exc}", file=sys.stderr)
        return 1
    for hub, path in world.params_files.items():
        print(f"hub {hub}: --params-file {path}", flush=True)
    print("ready", flush=True)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        await stop.wait()
    finally:
        await world.stop()
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="statehub: run the device simulators of a station, coupled")
    parser.add_argument("--config", default="hubs.toml")
    parser.add_argument("--run-dir", default="var/sim", help="logs, parameter files and pty links (var/sim)")
    parser.add_argument("--speed", type=float, default=1.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--loopback-port", type=int,
                        help="the station's controller port on 127.0.0.1: couples the operator to the simulators")
    return asyncio.run(_serve(parser.parse_args(argv)))


if __name__ == "__main__":
    exit_process(main())
