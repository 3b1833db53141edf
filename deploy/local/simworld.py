"""The simulated world of `hubctl up --mode sim`: every device simulator the station needs, coupled.

For each device that runs in `sim` mode (`--mode sim`, or `mode = "sim"` in hubs.toml)
the world starts the simulator that speaks its protocol, as a process of its own where
the simulator is a server, and tells the device's hub where it is:

* rsp, dock: the Modbus TCP coupler with tool changer and dock (`hubs.sim.toolchanger_modbus`),
  one process per changer, shared by its dock;
* ur: the fake UR controller, RTDE + dashboard + command port (`hubs.sim.ur_rtde_fake`), a
  process on a loopback address of its own, 127.0.N.2 (its ports are fixed);
* mir: the MiR REST API (`hubs.sim.mir_rest`), a process;
* camera: the tracker feed (`hubs.sim.camera_tracker --control`), a process fed the
  operator's position;
* rfid: the EM4100 reader on a pty (`hubs.sim.rfid_serial`), a process fed the badge;
* nutrunner (MCP23017 on a simulated I2C bus) and lift (CAN on python-can `virtual`, which
  only connects buses of one process): inside their hub process, started by the driver
  factory (`hubs.drivers.make_driver`); the world only sends their simulation parameters.

Devices with no protocol (the operator, the AGV) stay emulated. Each hub receives its
devices' simulator addresses and simulation parameters as a parameter-override file
(`hubctl hub --params-file`, `{resource: {parameter: value}}`), written to the world's
run directory. The robot's named poses get deterministic joint targets
(`hubs.sim.ur_poses`). Simulated time follows `--speed`: robot, MiR, lift, tool
changer piston, nutrunner and the operator's walk are that much faster.

The simulators are coupled as the real cell couples the devices (`hubs.sim.cell`): the
tool changer sees the robot's flange at a dock slot, the dock's sensors follow; and,
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
import socket
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from common.bus import Bus
from common.config import DeviceConfig, StationConfig, load_station
from common.keys import Keys
from common.messages import Codec
from common.model import Model
from common.zenoh_config import loopback_peer
from common.zenohbus import ZenohBus
from hubs.drivers import SIM_CAMERA_ZONES
from hubs.factory import effective_mode
from hubs.sim import cell, mir_rest
from hubs.sim.toolchanger_modbus import TOOLS
from hubs.sim.ur_poses import driver_poses, pose_table
from hubs.sim.ur_rtde_fake import COMMAND_PORT, DASHBOARD_PORT, RTDE_PORT

log = logging.getLogger("statehub.simworld")

OPERATOR_TAG = "5A0017C3E1"  # the simulated operator's badge
READY_TIMEOUT_S = 20.0
STOP_GRACE_S = 3.0
UR_ADDRESSES = range(100, 200)  # 127.0.N.2; the driver tests use 127.0.0.2 and 127.P.0.10+
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
        process = self.process
        if process is None or process.returncode is not None:
            return
        if process.stdin is not None:
            process.stdin.close()
        with contextlib.suppress(ProcessLookupError):
            process.terminate()
        try:
            await asyncio.wait_for(process.wait(), STOP_GRACE_S)
        except TimeoutError:
            with contextlib.suppress(ProcessLookupError):
                process.kill()
            await process.wait()


def _python(module: str, *args: str) -> list[str]:
    return [sys.executable, "-m", module, *args]


def free_robot_address(taken: set[str]) -> str:
    """A loopback address where RTDE, dashboard and command port are free (the ports are fixed)."""
    for n in UR_ADDRESSES:
        host = f"127.0.{n}.2"
        if host in taken:
            continue
        try:
            for port in (RTDE_PORT, DASHBOARD_PORT, COMMAND_PORT):
                with socket.socket() as s:
                    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                    s.bind((host, port))
        except OSError:
            continue
        return host
    raise SimulatorError(f"no free loopback address for a fake UR controller in 127.0.{UR_ADDRESSES[0]}-"
                         f"{UR_ADDRESSES[-1]}.2 (ports {RTDE_PORT}, {DASHBOARD_PORT}, {COMMAND_PORT})")


# --- the world ---------------------------------------------------------------------------------

@dataclass
class SimWorld:
    config: StationConfig
    model: Model
    run_dir: Path
    speed: float = 1.0
    seed: int = 0
    failure: Mapping[str, float] = field(default_factory=dict)
    mode: str | None = "sim"  # the `--mode` override; None: as in hubs.toml
    loopback_port: int | None = None  # the station's bus: couples the operator to camera, dock and RFID
    say: Say = print
    devices: dict[str, DeviceConfig] = field(default_factory=dict)  # resource -> device, sim devices only
    emulated: list[str] = field(default_factory=list)  # devices that stay emulated in sim mode: no simulator
    processes: dict[str, SimProcess] = field(default_factory=dict)
    overrides: dict[str, dict[str, Any]] = field(default_factory=dict)  # resource -> parameters
    params_files: dict[str, Path] = field(default_factory=dict)  # hub -> override file
    poses: dict[str, dict[str, tuple[float, ...]]] = field(default_factory=dict)  # robot -> pose -> joints
    _tasks: list[asyncio.Task[None]] = field(default_factory=list)
    _bus: Bus | None = None
    _log_handler: logging.Handler | None = None

    def __post_init__(self) -> None:
        for hub in self.config.hubs.values():
            for resource, device in hub.devices.items():
                chosen = effective_mode(device.type, device.mode, self.mode)
                if chosen == "sim":
                    self.devices[resource] = device
                elif self.mode == "sim" and chosen == "emulate":
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
            self._plan_in_process()
            await self._start_servers()
            self._write_params()
            await self._couple()
        except BaseException:
            await self.stop()
            raise
        for line in self.summary():
            self.say(line)

    async def stop(self) -> None:
        tasks, self._tasks = self._tasks, []
        for task in tasks:
            task.cancel()
        for task in tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        if self._bus is not None:
            with contextlib.suppress(Exception):
                await self._bus.close()
            self._bus = None
        await asyncio.gather(*(p.stop() for p in self.processes.values()))
        for resource in self.of_type("rfid"):
            with contextlib.suppress(OSError):
                self._rfid_link(resource).unlink()
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
        for resource, device in self.of_type("nutrunner", "lift").items():
            lines.append(f"  {resource} ({device.type}): simulated inside hub {self.config.hub_of(resource).name}")
        if self.emulated:
            lines.append(f"  emulated (no protocol simulator): {', '.join(self.emulated)}")
        return lines

    # --- planning the simulators -------------------------------------------------------------
    def _set(self, resource: str, **params: Any) -> None:
        self.overrides.setdefault(resource, {}).update(params)

    def _plan_in_process(self) -> None:
        for resource in self.of_type("nutrunner"):
            self._set(resource, sim_seed=self.seed, sim_fail_probability=float(self.failure.get(resource, 0.0)),
                      sim_spinup=0.05 / self.speed, sim_tighten=0.25 / self.speed, sim_reset=0.02 / self.speed)
        for resource in self.of_type("lift"):
            self._set(resource, sim_speed=400.0 * self.speed)

    def _changer_of(self, resource: str) -> str:
        """The coupler a changer or dock is wired to: a dock shares its changer's when that is simulated."""
        device = self.devices[resource]
        if device.type == "dock":
            changer = self.model.resource_by_name[resource].parameters.get("changer")
            if changer in self.devices and self.devices[changer].type == "rsp":
                return str(changer)
        return resource

    async def _start_servers(self) -> None:
        starts = []
        for changer in sorted({self._changer_of(r) for r in self.of_type("rsp", "dock")}):
            served = [r for r in self.of_type("rsp", "dock") if self._changer_of(r) == changer]
            starts.append(self._server(
                f"coupler-{changer}", f"Modbus coupler ({', '.join(served)})",
                _python("hubs.sim.toolchanger_modbus", "--host", "127.0.0.1", "--port", "0",
                        "--stroke-time", f"{max(0.05, 0.15 / self.speed):.4f}"),
                r"listening on (\S+)", served, self._modbus_params))
        for resource in self.of_type("mir"):
            starts.append(self._server(
                f"mir-{resource}", f"MiR REST API ({resource})",
                _python("hubs.sim.mir_rest", "--host", "127.0.0.1", "--port", "0", "--speed", f"{self.speed:g}"),
                r"listening on (\S+)", [resource], self._mir_params))
        for resource in self.of_type("camera"):
            starts.append(self._server(
                f"camera-{resource}", f"camera tracker feed ({resource})",
                _python("hubs.sim.camera_tracker", "--host", "127.0.0.1", "--port", "0", "--control"),
                r"listening on (\S+)", [resource], self._camera_params, control=True))
        for resource in self.of_type("rfid"):
            starts.append(self._server(
                f"rfid-{resource}", f"RFID reader ({resource})",
                _python("hubs.sim.rfid_serial", "--link", str(self._rfid_link(resource))),
                r"^(\S+)$", [resource], self._rfid_params, control=True))
        for resource in self.of_type("ur"):
            starts.append(self._robot(resource))
        await asyncio.gather(*starts)

    async def _server(self, name: str, what: str, argv: list[str], ready: str, resources: list[str],
                      params: Callable[[str, str], dict[str, Any]], control: bool = False) -> None:
        process = SimProcess(name, what, argv, self.run_dir / f"{name}.log", ready, control=control)
        self.processes[name] = process
        address = await process.start()
        for resource in resources:
            self._set(resource, **params(resource, address))

    async def _robot(self, resource: str, attempts: int = 3) -> None:
        spec = self.model.resource_by_name[resource].parameters
        self.poses[resource] = pose_table(spec["poses"], spec["allowed_moves"], spec["home"])
        taken = {p.address for p in self.processes.values()}
        for attempt in range(attempts):
            host = free_robot_address(taken)
            process = SimProcess(f"ur-{resource}", f"fake UR controller ({resource})",
                                 _python("hubs.sim.ur_rtde_fake", "--host", host), self.run_dir / f"ur-{resource}.log",
                                 r"^ready (\S+)$")
            self.processes[process.name] = process
            try:
                await process.start()
                break
            except SimulatorError:
                taken.add(host)  # taken meanwhile by someone else
                if attempt + 1 == attempts:
                    raise
        self._set(resource, host=process.address, motion_backend="sim", command_port=COMMAND_PORT,
                  poses=driver_poses(self.poses[resource]), joint_speed=1.05 * self.speed)

    @staticmethod
    def _host_port(address: str) -> tuple[str, int]:
        host, _, port = address.rpartition(":")
        return host, int(port)

    def _modbus_params(self, resource: str, address: str) -> dict[str, Any]:
        host, port = self._host_port(address)
        return {"host": host, "port": port, "device_id": 1}

    def _mir_params(self, resource: str, address: str) -> dict[str, Any]:
        host, port = self._host_port(address)
        return {"host": host, "port": port, "username": "admin", "password": "admin",
                "missions": {"kitting": mir_rest.KITTING_MISSION, "station": mir_rest.STATION_MISSION},
                "positions": {"kitting": list(mir_rest.KITTING_POSITION),
                              "station": list(mir_rest.STATION_POSITION)}}

    def _zones(self, resource: str) -> dict[str, list[list[float]]]:
        return dict(self.devices[resource].params.get("zones", SIM_CAMERA_ZONES))

    def _camera_params(self, resource: str, address: str) -> dict[str, Any]:
        host, port = self._host_port(address)
        return {"host": host, "port": port, "zones": self._zones(resource)}

    def _rfid_link(self, resource: str) -> Path:
        return self.run_dir.resolve() / f"{resource}.tty"

    def _rfid_params(self, resource: str, address: str) -> dict[str, Any]:
        return {"serial_port": str(self._rfid_link(resource)), "operators": {OPERATOR_TAG: "simulated operator"}}

    def _write_params(self) -> None:
        for hub in self.config.hubs.values():
            mine = {r: self.overrides[r] for r in hub.devices if r in self.overrides}
            if mine:
                path = self.run_dir / f"{hub.name}.params.json"
                path.write_text(json.dumps(mine, indent=2) + "\n", encoding="utf-8")
                self.params_files[hub.name] = path

    # --- coupling ----------------------------------------------------------------------------
    def _spawn(self, coroutine: Any, name: str) -> None:
        self._tasks.append(asyncio.create_task(coroutine, name=name))

    async def _couple(self) -> None:
        couplers: dict[str, cell.CouplerLink] = {}
        for changer in {self._changer_of(r) for r in self.of_type("rsp", "dock")}:
            host, port = self._host_port(self.processes[f"coupler-{changer}"].address)
            couplers[changer] = cell.CouplerLink(host, port)
        for changer, link in couplers.items():
            robot = self.model.resource_by_name[changer].parameters.get("robot")
            if self.devices[changer].type != "rsp" or robot not in self.of_type("ur"):
                continue
            dock_poses = self.model.resource_by_name[changer].parameters["dock_poses"]
            slots = {TOOLS.index(tool) + 1: self.poses[str(robot)][pose] for tool, pose in dock_poses.items()}
            tolerance = float(self.devices[str(robot)].params.get("joint_tolerance", 0.01))
            flange = cell.FlangeCoupling(cell.RobotLink(self.processes[f"ur-{robot}"].address, COMMAND_PORT),
                                         link, slots, tolerance)
            self._spawn(flange.run(), f"flange {changer}")
        if self.loopback_port is None:
            return
        self._bus = await ZenohBus(loopback_peer(self.loopback_port, self.config.network.lease_ms)).open()
        keys = self.config.keys
        for operator in (r.name for r in self.model.resources if r.device_type == "operator"):
            self._couple_operator(operator, keys, couplers)
        for resource in self.of_type("rfid"):
            badge = cell.BadgeCoupling(self._bus, keys, Codec(self.model.resource_by_name[resource]),
                                       self.processes[f"rfid-{resource}"].send, OPERATOR_TAG,
                                       delay=0.5 / self.speed, retry=3.0)
            self._spawn(badge.run(), f"badge {resource}")

    def _couple_operator(self, operator: str, keys: Keys, couplers: dict[str, cell.CouplerLink]) -> None:
        assert self._bus is not None
        cameras = [r for r in self.of_type("camera")
                   if self.model.resource_by_name[r].parameters.get("operator") == operator]
        docks = [r for r in self.of_type("dock")
                 if self.model.resource_by_name[r].parameters.get("operator") == operator]
        if not cameras and not docks:
            return
        walker = cell.Walker(self._zones(cameras[0]), speed=1.4 * self.speed) if cameras else None
        task_zones = dict(self.model.resource_by_name[cameras[0]].parameters["task_zones"]) if cameras else {}
        handheld: dict[str, list[str]] = {}
        for dock in docks:
            for tool, tasks in self.model.resource_by_name[dock].parameters.get("handheld_tasks", {}).items():
                handheld.setdefault(tool, []).extend(tasks)
        coupling = cell.OperatorCoupling(
            self._bus, keys, Codec(self.model.resource_by_name[operator]), task_zones, walker,
            [self.processes[f"camera-{c}"].send for c in cameras], handheld,
            [couplers[self._changer_of(d)] for d in docks])
        self._spawn(coupling.run(), f"operator {operator}")


async def start_world(config: StationConfig, model: Model, options: Any, loopback_port: int,
                      say: Say = print) -> SimWorld | None:
    """`hubctl up --mode sim`: the started world, or None after saying why it could not start."""
    world = SimWorld(config, model, Path(options.run_dir) / "sim", speed=options.speed, seed=options.seed,
                     failure=dict(options.failure), mode=options.mode, loopback_port=loopback_port, say=say)
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
    sys.exit(main())
