"""A fake UR10 controller speaking RTDE (port 30004) and the dashboard protocol (port 29999).

ur-rtde connects to the fixed ports 30004/29999, so each fake runs in its own process on
its own loopback address (``127.0.0.2``, ``127.0.0.3``, ... all route to ``lo`` on
Linux)::

    python -m hubs.sim.ur_rtde_fake --host 127.0.0.2|auto [--command-port 30099] [--rate 125]

It prints ``ready HOST`` once every port listens (``auto``: a 127.0.N.2, N in 100..199,
whose ports are free, scanned from a place given by the process id).  The wire format is in
``hubs.sim.ur_rtde_codec``, the robot (motion, modes, the emulated control script) in
``hubs.sim.ur_robot``, its kinematics in ``hubs.sim.ur_kinematics``; this module holds the
servers.  Served:

* **RTDE** (protocol version 2, also answers version 1): request protocol version
  ``V``, get controller version ``v`` (reports 5.11.1), setup outputs ``O`` (frequency
  + variable names → recipe id + types; *every* name gets a type: the official RTDE
  types for known names, register names by pattern, DOUBLE for anything else), setup
  inputs ``I`` (input registers and other inputs, accepted and recorded), start ``S``,
  pause ``P``, and data packages ``U`` streamed at min(requested, ``--rate``) Hz per
  started recipe; client ``U`` packages (input recipes) are accepted and recorded.
  Values: ``timestamp`` (s since the fake started), ``actual_q``/``target_q``,
  ``actual_qd``, ``actual_TCP_pose`` (UR10 forward kinematics of q), ``robot_mode``,
  ``safety_mode``, ``safety_status``, ``safety_status_bits``, ``robot_status_bits``,
  ``runtime_state`` and sensible constants for the rest.
* **Dashboard** (text lines): ``stop``, ``play``, ``pause``, ``unlock protective stop``,
  ``close safety popup``, ``close popup``, ``robotmode``, ``safetymode``,
  ``safetystatus``, ``power on``, ``power off``, ``brake release``,
  ``PolyscopeVersion``, ``is in remote control``, ``running``, ``programState``,
  ``get robot model``, ``get serial number``, ``restart safety``, ``quit``.
* **Script ports** 30001-30003: accept URScript and record it.  No URScript interpreter
  runs it; ur-rtde's own control script (``def rtde_control``) is *emulated at its
  register interface* instead: once it is uploaded the program counts as running
  (robot_status_bits bit 1, runtime_state PLAYING, output_int_register_0 = 1 "ready"),
  and commands written by ``RTDEControlInterface`` to the RTDE input registers are
  executed: 1 moveJ, 2 moveJ_IK, 3 moveL, 4 moveL_FK (synchronous or asynchronous, with
  the async progress word in output_int_register_2), 31 protective stop, 33/34 stopL/
  stopJ, 255 stop script; any other command is acknowledged ("done") and ignored.
  Dashboard ``stop``, a protective stop or power off end the emulated program.
* **Command port** (``--command-port``, default 30099; not a UR port, the simulator's
  side channel that the simulated motion backend and tests use), JSON lines, one reply
  line each ``{"ok": true, ...}`` / ``{"ok": false, "error": ...}``:
  ``{"cmd": "movej", "q": [6], "speed": rad/s}``, ``{"cmd": "movel", "pose": [6],
  "speed": m/s}`` (solved by numeric IK, then moved in joint space), ``{"cmd": "stop"}``,
  ``{"cmd": "protective_stop"}`` (a collision), ``{"cmd": "freeze", "on": bool}`` (RTDE
  data stops, connections stay: a hung controller), ``{"cmd": "remote_control", "on":
  bool}`` (moves are refused in local mode), ``{"cmd": "state"}`` (everything, for tests),
  ``{"cmd": "pose"}`` (only ``q`` and ``moving``), ``{"cmd": "watch_flange", "slots":
  {...}, "tolerance": rad}`` (the connection becomes the simulated cell's subscription to
  the flange's dock slot; the RTDE streams wait for its acknowledgement of a change,
  ``hubs.sim.ur_flange``).

Motion: joint-space linear interpolation, all joints arriving together, leading joint
at ``speed`` rad/s; it stops on ``stop`` (command port or dashboard), on a protective
stop, and when powered off.  Moves are refused unless the robot is RUNNING, in remote
control and not protective-stopped.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import struct
import sys
import time
from typing import Any

from hubs.protocols.ur import (
    COMMAND_PORT,
    DASHBOARD_PORT,
    IDLE,
    NORMAL,
    POWER_OFF,
    POWER_ON,
    PROTECTIVE_STOP,
    ROBOT_MODES,
    RTDE_PORT,
    RUNNING,
    SAFETY_MODES,
    SCRIPT_PORTS,
)
from hubs.sim.registry import SimServer, SimulatedDevice, SimulatorPlugin, python_module
from hubs.sim.ur_flange import FlangeWatch
from hubs.sim.ur_kinematics import inverse, tcp_pose
from hubs.sim.ur_poses import driver_poses, pose_table
from hubs.sim.ur_robot import HOME_Q, FakeRobot
from hubs.sim.ur_rtde_codec import (
    DATA_PACKAGE,
    FORMATS,
    GET_URCONTROL_VERSION,
    PAUSE,
    REQUEST_PROTOCOL_VERSION,
    SETUP_INPUTS,
    SETUP_OUTPUTS,
    START,
    encode,
    message,
    rtde_type,
)

CONTROLLER_VERSION = (5, 11, 1, 108318)
POLYSCOPE = "URSoftware 5.11.1.108318 (Dec 06 2021)"
AUTO_HOSTS = range(100, 200)  # `--host auto`: 127.0.N.2; the driver tests use 127.0.0.2 and 127.P.0.10+

__all__ = ["HOME_Q", "FakeController", "FakeRobot"]


class FakeController:
    def __init__(
        self,
        robot: FakeRobot,
        host: str,
        *,
        rtde_port: int = RTDE_PORT,
        dashboard_port: int = DASHBOARD_PORT,
        command_port: int = COMMAND_PORT,
        script_ports: tuple[int, ...] = SCRIPT_PORTS,
        rate: float = 125.0,
    ) -> None:
        self.robot = robot
        self.host = host
        self.ports = {"rtde": rtde_port, "dashboard": dashboard_port, "command": command_port}
        self.script_ports = script_ports
        self.rate = rate
        self.recipes_requested: list[list[str]] = []
        self.flange: FlangeWatch | None = None  # the simulated cell's subscription (hubs.sim.ur_flange)
        self._servers: list[asyncio.Server] = []

    async def start(self) -> None:
        handlers = [
            (self.ports["rtde"], self._rtde),
            (self.ports["dashboard"], self._dashboard),
            (self.ports["command"], self._command),
        ]
        handlers += [(port, self._script) for port in self.script_ports]
        for port, handler in handlers:
            self._servers.append(await asyncio.start_server(handler, self.host, port, reuse_address=True))

    async def stop(self) -> None:
        for server in self._servers:
            server.close()
        self._servers.clear()

    # RTDE ------------------------------------------------------------------------------

    async def _rtde(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        recipes: dict[int, list[str]] = {}
        input_recipes: dict[int, list[str]] = {}
        streamer: asyncio.Task[None] | None = None
        frequency = self.rate
        try:
            while True:
                header = await reader.readexactly(3)
                size, kind = struct.unpack(">HB", header)
                payload = await reader.readexactly(size - 3)
                if kind == REQUEST_PROTOCOL_VERSION:
                    writer.write(message(kind, b"\x01"))
                elif kind == GET_URCONTROL_VERSION:
                    writer.write(message(kind, struct.pack(">IIII", *CONTROLLER_VERSION)))
                elif kind == SETUP_OUTPUTS:
                    requested = struct.unpack(">d", payload[:8])[0] if len(payload) >= 8 else self.rate
                    names = [n for n in payload[8:].decode(errors="replace").split(",") if n]
                    frequency = min(self.rate, requested) if requested > 0 else self.rate
                    recipe_id = len(recipes) + 1
                    recipes[recipe_id] = names
                    self.recipes_requested.append(names)
                    types = ",".join(rtde_type(n) for n in names)
                    writer.write(message(kind, bytes([recipe_id]) + types.encode()))
                elif kind == SETUP_INPUTS:
                    names = [n for n in payload.decode(errors="replace").split(",") if n]
                    recipe_id = len(input_recipes) + 1
                    input_recipes[recipe_id] = names
                    types = ",".join(rtde_type(n) for n in names)
                    writer.write(message(kind, bytes([recipe_id]) + types.encode()))
                elif kind == START:
                    if streamer is None:
                        streamer = asyncio.create_task(self._stream(writer, recipes, frequency))
                    writer.write(message(kind, b"\x01"))
                elif kind == PAUSE:
                    if streamer is not None:
                        streamer.cancel()
                        streamer = None
                    writer.write(message(kind, b"\x01"))
                elif kind == DATA_PACKAGE and payload:
                    self._record_inputs(input_recipes.get(payload[0], []), payload[1:])
                    self.robot.update()
                    self.robot.process_inputs()
                await writer.drain()
        except (asyncio.IncompleteReadError, ConnectionError, OSError):
            pass
        finally:
            if streamer is not None:
                streamer.cancel()
            writer.close()

    def _record_inputs(self, names: list[str], data: bytes) -> None:
        offset = 0
        for name in names:
            fmt = ">" + FORMATS[rtde_type(name)]
            size = struct.calcsize(fmt)
            if offset + size > len(data):
                return
            values = struct.unpack_from(fmt, data, offset)
            self.robot.inputs[name] = values if len(values) > 1 else values[0]
            offset += size

    async def _stream(self, writer: asyncio.StreamWriter, recipes: dict[int, list[str]], frequency: float) -> None:
        period = 1.0 / frequency
        next_time = time.monotonic()
        while True:
            next_time += period
            await asyncio.sleep(max(0.0, next_time - time.monotonic()))
            if self.robot.frozen:
                continue
            self.robot.update()
            if self.flange is not None:  # the cell knows where the flange is before anyone sees it there
                await self.flange.announce(self.robot.q)
            for recipe_id, names in recipes.items():
                body = bytes([recipe_id]) + b"".join(encode(rtde_type(n), self.robot.value(n)) for n in names)
                writer.write(message(DATA_PACKAGE, body))
            try:
                await writer.drain()
            except (ConnectionError, OSError):
                return

    # dashboard -------------------------------------------------------------------------

    def dashboard_reply(self, line: str) -> str:
        robot = self.robot
        robot.update()
        cmd = line.strip()
        low = cmd.lower()
        if low == "stop":
            robot.stop_program()
            return "Stopped"
        if low == "play":
            return "Starting program"
        if low == "pause":
            robot.stop_program()
            return "Pausing program"
        if low == "unlock protective stop":
            if robot.safety_mode != PROTECTIVE_STOP:
                return "Protective stop releasing"
            if robot.clock() - robot.protective_since < robot.unlock_delay:
                return (
                    "Cannot unlock protective stop until 5s after occurrence. "
                    "Always inspect cause of protective stop before unlocking"
                )
            robot.safety_mode = NORMAL
            return "Protective stop releasing"
        if low == "close safety popup":
            return "closing safety popup"
        if low == "close popup":
            return "closing popup"
        if low == "robotmode":
            return f"Robotmode: {ROBOT_MODES.get(robot.robot_mode, 'UNKNOWN')}"
        if low == "safetymode":
            return f"Safetymode: {SAFETY_MODES.get(robot.safety_mode, 'UNKNOWN')}"
        if low == "safetystatus":
            return f"Safetystatus: {SAFETY_MODES.get(robot.safety_mode, 'UNKNOWN')}"
        if low == "power on":
            if robot.robot_mode == POWER_OFF:
                robot.robot_mode = IDLE
            return "Powering on"
        if low == "power off":
            robot.stop_program()
            robot.robot_mode = POWER_OFF
            return "Powering off"
        if low == "brake release":
            if robot.robot_mode in (IDLE, POWER_ON):
                robot.robot_mode = RUNNING
            return "Brake releasing"
        if low == "polyscopeversion":
            return POLYSCOPE
        if low == "is in remote control":
            return "true" if robot.remote_control else "false"
        if low == "running":
            return f"Program running: {'true' if robot.program_running else 'false'}"
        if low == "programstate":
            return f"{'PLAYING' if robot.program_running else 'STOPPED'} <unnamed>"
        if low == "get robot model":
            return "UR10"
        if low == "get serial number":
            return "20195500000"
        if low == "restart safety":
            robot.safety_mode = NORMAL
            robot.robot_mode = POWER_OFF
            return "Restarting safety"
        if low == "quit":
            return "Disconnected"
        return f"could not understand: '{cmd}'"

    async def _dashboard(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            writer.write(b"Connected: Universal Robots Dashboard Server\n")
            await writer.drain()
            while line := await reader.readline():
                reply = self.dashboard_reply(line.decode(errors="replace"))
                writer.write(reply.encode() + b"\n")
                await writer.drain()
                if reply == "Disconnected":
                    break
        except (ConnectionError, OSError):
            pass
        finally:
            writer.close()

    # side channel and script ports -----------------------------------------------------

    def command_reply(self, request: dict[str, Any]) -> dict[str, Any]:
        robot = self.robot
        robot.update()
        cmd = request.get("cmd")
        if cmd in ("movej", "movel"):
            refused = robot.refuse_motion()
            if refused:
                return {"ok": False, "error": refused}
            if cmd == "movej":
                q = [float(v) for v in request["q"]]
            else:
                solved = inverse([float(v) for v in request["pose"]], robot.q)
                if solved is None:
                    return {"ok": False, "error": "no inverse kinematics solution"}
                q = solved
            if len(q) != 6:
                return {"ok": False, "error": "6 joint values needed"}
            speed = float(request.get("speed", 1.05 if cmd == "movej" else 0.25))
            robot.movej(q, speed if cmd == "movej" else speed * 4)  # movel: m/s, roughly 4 rad/s per m/s
            return {"ok": True, "target": q}
        if cmd == "stop":
            robot.stop()
            return {"ok": True}
        if cmd == "protective_stop":
            robot.protective_stop()
            return {"ok": True}
        if cmd == "freeze":
            robot.frozen = bool(request.get("on", True))
            return {"ok": True}
        if cmd == "remote_control":
            robot.remote_control = bool(request.get("on", True))
            return {"ok": True}
        if cmd == "pose":
            return {"ok": True, "q": robot.q, "moving": robot.moving}
        if cmd == "state":
            return {
                "ok": True,
                "q": robot.q,
                "tcp": tcp_pose(robot.q),
                "moving": robot.moving,
                "target": robot.target,
                "robot_mode": robot.robot_mode,
                "safety_mode": robot.safety_mode,
                "scripts": robot.scripts,
                "script_running": robot.script_running,
                "commands_seen": robot.commands_seen,
                "recipes": self.recipes_requested,
                "inputs": sorted(robot.inputs),
            }
        return {"ok": False, "error": f"unknown command {cmd!r}"}

    async def _command(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            while line := await reader.readline():
                try:
                    request = json.loads(line)
                    if isinstance(request, dict) and request.get("cmd") == "watch_flange":
                        await self._watch_flange(request, reader, writer)
                        return
                    reply = self.command_reply(request if isinstance(request, dict) else {})
                except (ValueError, KeyError, TypeError) as exc:
                    reply = {"ok": False, "error": f"bad request: {exc}"}
                writer.write(json.dumps(reply).encode() + b"\n")
                await writer.drain()
        except (ConnectionError, OSError):
            pass
        finally:
            writer.close()

    async def _watch_flange(self, request: dict[str, Any], reader: asyncio.StreamReader,
                            writer: asyncio.StreamWriter) -> None:
        """This connection becomes the cell's flange subscription (hubs.sim.ur_flange) until it closes."""
        slots = {int(slot): [float(v) for v in q] for slot, q in request["slots"].items()}
        watch = FlangeWatch(slots, float(request.get("tolerance", 0.01)), reader, writer)
        if self.flange is not None:
            self.flange.close()
        self.flange = watch
        writer.write(json.dumps({"ok": True}).encode() + b"\n")
        await writer.drain()
        await watch.closed.wait()

    async def _script(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        chunks = []
        try:
            while data := await reader.read(65536):
                chunks.append(data)
                text = b"".join(chunks).decode(errors="replace")
                if text.rstrip().endswith("end"):  # a complete program: def ... end
                    self.robot.script_uploaded(text)
                    chunks = []
        except (ConnectionError, OSError):
            pass
        finally:
            writer.close()


async def _start(args: argparse.Namespace) -> FakeController:
    """The started controller; with `--host auto` on a 127.0.N.2 whose ports are free."""
    if args.host == "auto":
        # Scanned from a place of this process's own: the first free address would be the one another
        # run's fake just left, and whoever still dials it (a hub of that run) would reach this one.
        start = os.getpid() % len(AUTO_HOSTS)
        hosts = [f"127.0.{n}.2" for n in (*AUTO_HOSTS[start:], *AUTO_HOSTS[:start])]
    else:
        hosts = [args.host]
    for host in hosts:
        robot = FakeRobot(
            robot_mode=POWER_OFF if args.powered_off else RUNNING,
            unlock_delay=args.unlock_delay,
            remote_control=not args.local_control,
        )
        controller = FakeController(
            robot,
            host,
            rtde_port=args.rtde_port,
            dashboard_port=args.dashboard_port,
            command_port=args.command_port,
            script_ports=() if args.no_script_ports else SCRIPT_PORTS,
            rate=args.rate,
        )
        try:
            await controller.start()
            return controller
        except OSError:
            await controller.stop()
            if len(hosts) == 1:
                raise
    raise OSError(f"no free loopback address for a fake UR controller in 127.0.{AUTO_HOSTS[0]}.2 .. "
                  f"127.0.{AUTO_HOSTS[-1]}.2 "
                  f"(ports {args.rtde_port}, {args.dashboard_port}, {args.command_port})")


async def _serve(args: argparse.Namespace) -> None:
    controller = await _start(args)
    print(f"ready {controller.host}", flush=True)
    try:
        await asyncio.Event().wait()
    finally:
        await controller.stop()


# --- as a simulator plugin (device type ur) ----------------------------------------------------

# A real controller streams RTDE in real time; this fake is a Python process that a loaded machine stalls
# for hundreds of milliseconds (its stream then stops, the timestamp with it). The driver's default
# (0.25 s, 31 missed samples of a real controller) would restart its worker at every such stall.
SIM_STALE_AFTER_S = 1.0


def _server(device: SimulatedDevice) -> SimServer:
    # The model names the poses; the simulated cell gives each a joint target (hubs.sim.ur_poses).
    table = pose_table(device.model["poses"], device.model["allowed_moves"], device.model["home"])
    return SimServer(
        python_module("hubs.sim.ur_rtde_fake", "--host", "auto"), ready=r"^ready (\S+)$",
        driver_params=lambda host: {"host": host, "motion_backend": "sim", "command_port": COMMAND_PORT,
                                    "poses": driver_poses(table), "joint_speed": 1.05 * device.speed,
                                    "stale_after": SIM_STALE_AFTER_S})


PLUGIN = SimulatorPlugin("fake UR controller", server=_server,
                         defaults={"host": "127.0.0.2", "motion_backend": "sim", "command_port": COMMAND_PORT})


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Fake UR10 controller: RTDE, dashboard and a command side channel")
    parser.add_argument("--host", default="127.0.0.2",
                        help="loopback address to bind (127.0.0.2, 127.0.0.3, ...); auto: a free 127.0.N.2, "
                             f"N in {AUTO_HOSTS[0]}..{AUTO_HOSTS[-1]}")
    parser.add_argument("--rtde-port", type=int, default=RTDE_PORT)
    parser.add_argument("--dashboard-port", type=int, default=DASHBOARD_PORT)
    parser.add_argument("--command-port", type=int, default=COMMAND_PORT)
    parser.add_argument("--no-script-ports", action="store_true", help="do not listen on 30001-30003")
    parser.add_argument("--rate", type=float, default=125.0, help="max RTDE data rate, Hz")
    parser.add_argument("--unlock-delay", type=float, default=0.0, help="s before a protective stop may be unlocked")
    parser.add_argument("--powered-off", action="store_true", help="start in POWER_OFF (power on, brake release)")
    parser.add_argument("--local-control", action="store_true", help="start in local control: moves refused")
    args = parser.parse_args(argv)
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(_serve(args))
    return 0


if __name__ == "__main__":
    sys.exit(main())
