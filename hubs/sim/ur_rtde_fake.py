"""A fake UR10 controller speaking RTDE (port 30004) and the dashboard protocol (port 29999).

ur-rtde connects to the fixed ports 30004/29999, so each fake runs in its own process on
its own loopback address (``127.0.0.2``, ``127.0.0.3``, ... all route to ``lo`` on
Linux)::

    python -m hubs.sim.ur_rtde_fake --host 127.0.0.2 [--command-port 30099] [--rate 125]

It prints ``ready HOST`` once every port listens.  Served:

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
  ``{"cmd": "pose"}`` (only ``q`` and ``moving``: what a simulated cell polls to know
  where the flange is).

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
import math
import re
import struct
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

RTDE_PORT, DASHBOARD_PORT, COMMAND_PORT = 30004, 29999, 30099
SCRIPT_PORTS = (30001, 30002, 30003)
CONTROLLER_VERSION = (5, 11, 1, 108318)
POLYSCOPE = "URSoftware 5.11.1.108318 (Dec 06 2021)"

# -- RTDE message types and data types ----------------------------------------------------

REQUEST_PROTOCOL_VERSION = ord("V")
GET_URCONTROL_VERSION = ord("v")
TEXT_MESSAGE = ord("M")
DATA_PACKAGE = ord("U")
SETUP_OUTPUTS = ord("O")
SETUP_INPUTS = ord("I")
START = ord("S")
PAUSE = ord("P")

FORMATS = {
    "BOOL": "?",
    "UINT8": "B",
    "UINT32": "I",
    "UINT64": "Q",
    "INT32": "i",
    "DOUBLE": "d",
    "VECTOR3D": "3d",
    "VECTOR6D": "6d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}

_V6 = "VECTOR6D"
OUTPUT_TYPES: dict[str, str] = {
    "timestamp": "DOUBLE",
    **dict.fromkeys(
        [
            "target_q",
            "target_qd",
            "target_qdd",
            "target_current",
            "target_moment",
            "actual_q",
            "actual_qd",
            "actual_current",
            "actual_current_window",
            "joint_control_output",
            "actual_TCP_pose",
            "actual_TCP_speed",
            "actual_TCP_force",
            "target_TCP_pose",
            "target_TCP_speed",
            "joint_temperatures",
            "actual_joint_voltage",
            "payload_inertia",
            "ft_raw_wrench",
            "actual_current_as_torque",
            "tcp_offset",
        ],
        _V6,
    ),
    "actual_digital_input_bits": "UINT64",
    "actual_digital_output_bits": "UINT64",
    "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32",
    "safety_status": "INT32",
    "actual_tool_accelerometer": "VECTOR3D",
    "elbow_position": "VECTOR3D",
    "elbow_velocity": "VECTOR3D",
    "payload_cog": "VECTOR3D",
    "runtime_state": "UINT32",
    "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32",
    "analog_io_types": "UINT32",
    "euromap67_input_bits": "UINT32",
    "euromap67_output_bits": "UINT32",
    "tool_mode": "UINT32",
    "tool_analog_input_types": "UINT32",
    "tool_output_voltage": "INT32",
    "output_bit_registers0_to_31": "UINT32",
    "output_bit_registers32_to_63": "UINT32",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "script_control_line": "UINT32",
    "time_scale_source": "UINT32",
    "tool_output_mode": "UINT8",
    "tool_digital_output0_mode": "UINT8",
    "tool_digital_output1_mode": "UINT8",
    "speed_slider_mask": "UINT32",
    "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8",
    "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8",
    "standard_analog_output_type": "UINT8",
    "external_force_torque": _V6,
}
_REGISTER = re.compile(r"^(input|output)_(bit|int|double)_register_(\d+)$")


def rtde_type(name: str) -> str:
    """The RTDE type of a variable; permissive: unknown names are DOUBLE."""
    if name in OUTPUT_TYPES:
        return OUTPUT_TYPES[name]
    match = _REGISTER.match(name)
    if match:
        return {"bit": "BOOL", "int": "INT32", "double": "DOUBLE"}[match.group(2)]
    return "DOUBLE"


def encode(kind: str, value: Any) -> bytes:
    fmt = FORMATS[kind]
    if fmt[0].isdigit():
        return struct.pack(">" + fmt, *value)
    return struct.pack(">" + fmt, value)


def default_value(kind: str) -> Any:
    return {
        "BOOL": False,
        "VECTOR3D": [0.0] * 3,
        "VECTOR6D": [0.0] * 6,
        "VECTOR6INT32": [0] * 6,
        "VECTOR6UINT32": [0] * 6,
        "DOUBLE": 0.0,
    }.get(kind, 0)


def message(kind: int, payload: bytes = b"") -> bytes:
    return struct.pack(">HB", len(payload) + 3, kind) + payload


# -- UR10 kinematics ----------------------------------------------------------------------

UR10_DH = (  # d, a, alpha
    (0.1273, 0.0, math.pi / 2),
    (0.0, -0.612, 0.0),
    (0.0, -0.5723, 0.0),
    (0.163941, 0.0, math.pi / 2),
    (0.1157, 0.0, -math.pi / 2),
    (0.0922, 0.0, 0.0),
)
Mat = list[list[float]]


def _matmul(a: Mat, b: Mat) -> Mat:
    return [[sum(a[i][k] * b[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def forward(q: list[float]) -> Mat:
    t: Mat = [[1.0 if i == j else 0.0 for j in range(4)] for i in range(4)]
    for theta, (d, a, alpha) in zip(q, UR10_DH, strict=True):
        ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
        t = _matmul(t, [[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0, sa, ca, d], [0, 0, 0, 1]])
    return t


def rotvec_of(r: Mat) -> list[float]:
    cos = max(-1.0, min(1.0, (r[0][0] + r[1][1] + r[2][2] - 1) / 2))
    angle = math.acos(cos)
    if angle < 1e-9:
        return [0.0, 0.0, 0.0]
    if math.pi - angle < 1e-6:  # 180°: axis from the diagonal
        axis = [math.sqrt(max(0.0, (r[i][i] + 1) / 2)) for i in range(3)]
        if axis[0] > 1e-6:
            axis[1] = math.copysign(axis[1], r[0][1])
            axis[2] = math.copysign(axis[2], r[0][2])
        elif axis[1] > 1e-6:
            axis[2] = math.copysign(axis[2], r[1][2])
        return [angle * v for v in axis]
    k = angle / (2 * math.sin(angle))
    return [k * (r[2][1] - r[1][2]), k * (r[0][2] - r[2][0]), k * (r[1][0] - r[0][1])]


def matrix_of(rv: list[float]) -> Mat:
    angle = math.sqrt(sum(v * v for v in rv))
    if angle < 1e-12:
        return [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    x, y, z = (v / angle for v in rv)
    c, s, t = math.cos(angle), math.sin(angle), 1 - math.cos(angle)
    return [
        [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
    ]


def tcp_pose(q: list[float]) -> list[float]:
    t = forward(q)
    return [t[0][3], t[1][3], t[2][3], *rotvec_of([row[:3] for row in t[:3]])]


def _pose_error(pose: list[float], q: list[float]) -> list[float]:
    t = forward(q)
    r_now = [row[:3] for row in t[:3]]
    r_goal = matrix_of(pose[3:])
    r_err = [[sum(r_goal[i][k] * r_now[j][k] for k in range(3)) for j in range(3)] for i in range(3)]  # goal · nowᵀ
    return [pose[0] - t[0][3], pose[1] - t[1][3], pose[2] - t[2][3], *rotvec_of(r_err)]


def _solve(a: list[list[float]], b: list[float]) -> list[float]:
    n = len(b)
    m = [[*row, b[i]] for i, row in enumerate(a)]
    for col in range(n):
        pivot = max(range(col, n), key=lambda r: abs(m[r][col]))
        m[col], m[pivot] = m[pivot], m[col]
        if abs(m[col][col]) < 1e-12:
            raise ArithmeticError("singular")
        for r in range(n):
            if r != col:
                f = m[r][col] / m[col][col]
                for c in range(col, n + 1):
                    m[r][c] -= f * m[col][c]
    return [m[i][n] / m[i][i] for i in range(n)]


def inverse(pose: list[float], seed: list[float], iterations: int = 200) -> list[float] | None:
    """Damped least-squares IK from ``seed``; None when it does not converge."""
    q = list(seed)
    damping = 1e-3
    for _ in range(iterations):
        err = _pose_error(pose, q)
        if max(abs(e) for e in err) < 1e-6:
            return q
        jac = [[0.0] * 6 for _ in range(6)]
        for j in range(6):
            dq = list(q)
            dq[j] += 1e-6
            e2 = _pose_error(pose, dq)
            for i in range(6):
                jac[i][j] = (err[i] - e2[i]) / 1e-6
        jtj = [
            [sum(jac[k][i] * jac[k][j] for k in range(6)) + (damping if i == j else 0.0) for j in range(6)]
            for i in range(6)
        ]
        jte = [sum(jac[k][i] * err[k] for k in range(6)) for i in range(6)]
        try:
            step = _solve(jtj, jte)
        except ArithmeticError:
            return None
        scale = min(1.0, 0.5 / max(1e-12, max(abs(s) for s in step)))
        q = [qi + scale * si for qi, si in zip(q, step, strict=True)]
    return q if max(abs(e) for e in _pose_error(pose, q)) < 1e-5 else None


# -- the robot ----------------------------------------------------------------------------

ROBOT_MODES = {
    -1: "NO_CONTROLLER",
    0: "DISCONNECTED",
    1: "CONFIRM_SAFETY",
    2: "BOOTING",
    3: "POWER_OFF",
    4: "POWER_ON",
    5: "IDLE",
    6: "BACKDRIVE",
    7: "RUNNING",
}
SAFETY_MODES = {
    1: "NORMAL",
    2: "REDUCED",
    3: "PROTECTIVE_STOP",
    4: "RECOVERY",
    5: "SAFEGUARD_STOP",
    6: "SYSTEM_EMERGENCY_STOP",
    7: "ROBOT_EMERGENCY_STOP",
    8: "VIOLATION",
    9: "FAULT",
}
RUNNING, POWER_OFF, IDLE = 7, 3, 5
NORMAL, PROTECTIVE_STOP = 1, 3
RUNTIME_STOPPED, RUNTIME_PLAYING = 1, 2
HOME_Q = [0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0]


@dataclass
class FakeRobot:
    q: list[float] = field(default_factory=lambda: list(HOME_Q))
    robot_mode: int = RUNNING
    safety_mode: int = NORMAL
    remote_control: bool = True
    frozen: bool = False
    unlock_delay: float = 0.0
    clock: Callable[[], float] = time.monotonic
    target: list[float] | None = None
    speed: float = 1.05
    qd: list[float] = field(default_factory=lambda: [0.0] * 6)
    protective_since: float = 0.0
    started: float = 0.0
    _last: float = 0.0
    scripts: list[str] = field(default_factory=list)
    inputs: dict[str, Any] = field(default_factory=dict)
    # ur-rtde control script emulation (see ``script_uploaded``)
    script_running: bool = False
    executing_cmd: bool = False
    out_int: dict[int, int] = field(default_factory=dict)
    async_count: int = 0
    async_op: int = 0
    async_active: bool = False
    commands_seen: list[int] = field(default_factory=list)
    done_when_stopped: bool = False  # a synchronous move signals "done" when the motion ends

    def __post_init__(self) -> None:
        self.started = self._last = self.clock()

    # -- the ur-rtde control script, emulated at its register interface ------------------

    def script_uploaded(self, text: str) -> None:
        """URScript arrived on a script port.  ur-rtde's ``rtde_control`` script is emulated at
        its RTDE register interface (cmd in input_int_register_0, arguments in
        input_int_register_1 and input_double_register_0..7, handshake in
        output_int_register_0: 1 ready, 2 done; async progress in output_int_register_2).
        Other scripts are only recorded."""
        self.scripts.append(text)
        if "def rtde_control" in text and self.robot_mode == RUNNING:
            self.script_running, self.executing_cmd = True, False
            self.out_int = {0: 1, 1: 0, 2: 0}
            self._async_progress(-1)

    def stop_program(self) -> None:
        self.stop()
        self.script_running, self.executing_cmd = False, False
        self.out_int[0] = 0
        self._async_progress(-1)

    def _async_progress(self, value: int) -> None:
        self.async_count = (self.async_count + 1) % 128
        if value == 0:
            self.async_op = (self.async_op + 1) % 128
        reg = self.async_count * 65536 + self.async_op * 16777216
        if value >= 0:
            reg += min(value, 32767) + 32768
        self.out_int[2] = reg
        self.async_active = value >= 0

    def process_inputs(self) -> None:
        if not self.script_running:
            return
        cmd = int(self.inputs.get("input_int_register_0", 0))
        if cmd == 0:
            self.executing_cmd = False
            self.out_int[0] = 1  # signal_ready
            return
        if self.executing_cmd:
            return
        self.executing_cmd = True
        self.commands_seen.append(cmd)
        regs = [float(self.inputs.get(f"input_double_register_{i}", 0.0)) for i in range(8)]
        if cmd in (1, 2, 3, 4) and self.refuse_motion() is None:  # movej, movej_ik, movel, movel_fk
            q: list[float] | None = regs[:6] if cmd in (1, 4) else inverse(regs[:6], self.q)
            if q is not None:
                self.movej(q, regs[6] if cmd in (1, 2) else max(regs[6] * 4, 1e-3))
                if int(self.inputs.get("input_int_register_1", 0)) == 1:
                    self._async_progress(0)
                else:
                    self.done_when_stopped = True
                    return
        elif cmd in (33, 34):  # stopl, stopj
            self.stop()
        elif cmd == 31:  # protective_stop
            self.protective_stop()
        elif cmd == 255:  # stop script
            self.script_running = False
            return
        self.out_int[0] = 2  # signal_done_with_cmd

    @property
    def moving(self) -> bool:
        return self.target is not None

    @property
    def program_running(self) -> bool:
        return self.script_running or self.moving

    def update(self) -> None:
        now = self.clock()
        dt, self._last = now - self._last, now
        if self.target is None:
            self.qd = [0.0] * 6
            return
        diffs = [t - q for t, q in zip(self.target, self.q, strict=True)]
        lead = max(abs(d) for d in diffs)
        step = self.speed * dt
        if lead <= step or lead < 1e-12:
            self.q, self.target, self.qd = list(self.target), None, [0.0] * 6
            self._motion_ended()
            return
        frac = step / lead
        self.q = [q + d * frac for q, d in zip(self.q, diffs, strict=True)]
        self.qd = [d / lead * self.speed for d in diffs]

    def refuse_motion(self) -> str | None:
        if self.robot_mode != RUNNING:
            return f"robot not running ({ROBOT_MODES.get(self.robot_mode)})"
        if self.safety_mode != NORMAL:
            return f"safety mode {SAFETY_MODES.get(self.safety_mode)}"
        if not self.remote_control:
            return "robot is in local control"
        return None

    def movej(self, q: list[float], speed: float) -> None:
        self.update()
        self.target, self.speed = [float(v) for v in q], max(1e-3, float(speed))

    def stop(self) -> None:
        self.update()
        self.target = None
        self.qd = [0.0] * 6
        self._motion_ended()

    def _motion_ended(self) -> None:
        if self.async_active:
            self._async_progress(-1)
        if self.done_when_stopped:
            self.done_when_stopped = False
            if self.script_running:
                self.out_int[0] = 2

    def protective_stop(self) -> None:
        self.stop_program()
        self.safety_mode, self.protective_since = PROTECTIVE_STOP, self.clock()

    def value(self, name: str) -> Any:
        kind = rtde_type(name)
        if name == "timestamp":
            return self.clock() - self.started
        if name in ("actual_q", "target_q"):
            return self.q
        if name in ("actual_qd", "target_qd"):
            return self.qd
        if name in ("actual_TCP_pose", "target_TCP_pose"):
            return tcp_pose(self.q)
        if name == "robot_mode":
            return self.robot_mode
        if name in ("safety_mode", "safety_status"):
            return self.safety_mode
        if name == "safety_status_bits":
            return (1 if self.safety_mode == NORMAL else 0) | (4 if self.safety_mode == PROTECTIVE_STOP else 0)
        if name == "robot_status_bits":
            return (1 if self.robot_mode in (4, 5, 6, 7) else 0) | (2 if self.program_running else 0)
        if name == "runtime_state":
            return RUNTIME_PLAYING if self.program_running else RUNTIME_STOPPED
        match = _REGISTER.match(name)
        if match and match.group(1) == "output" and match.group(2) == "int":
            return self.out_int.get(int(match.group(3)), 0)
        if name == "joint_mode":
            return [253 if self.robot_mode == RUNNING else 236] * 6
        if name in ("speed_scaling", "target_speed_fraction"):
            return 1.0
        if name == "joint_temperatures":
            return [31.5] * 6
        if name in ("actual_main_voltage", "actual_robot_voltage"):
            return 48.0
        if name == "actual_tool_accelerometer":
            return [0.0, 0.0, 9.81]
        return default_value(kind)


# -- servers ------------------------------------------------------------------------------


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
            if robot.robot_mode in (IDLE, 4):
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
                    reply = self.command_reply(request if isinstance(request, dict) else {})
                except (ValueError, KeyError, TypeError) as exc:
                    reply = {"ok": False, "error": f"bad request: {exc}"}
                writer.write(json.dumps(reply).encode() + b"\n")
                await writer.drain()
        except (ConnectionError, OSError):
            pass
        finally:
            writer.close()

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


async def _serve(args: argparse.Namespace) -> None:
    robot = FakeRobot(
        robot_mode=POWER_OFF if args.powered_off else RUNNING,
        unlock_delay=args.unlock_delay,
        remote_control=not args.local_control,
    )
    controller = FakeController(
        robot,
        args.host,
        rtde_port=args.rtde_port,
        dashboard_port=args.dashboard_port,
        command_port=args.command_port,
        script_ports=() if args.no_script_ports else SCRIPT_PORTS,
        rate=args.rate,
    )
    await controller.start()
    print(f"ready {args.host}", flush=True)
    try:
        await asyncio.Event().wait()
    finally:
        await controller.stop()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Fake UR10 controller: RTDE, dashboard and a command side channel")
    parser.add_argument("--host", default="127.0.0.2", help="loopback address to bind (127.0.0.2, 127.0.0.3, ...)")
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
