"""The fake UR controller's robot: joint motion, modes, and ur-rtde's control script emulated.

Motion is joint-space linear interpolation, all joints arriving together, the leading
joint at ``speed`` rad/s, evaluated lazily from the clock (``update``). ur-rtde's
``rtde_control`` URScript is not run but emulated at its RTDE register interface
(``script_uploaded``, ``process_inputs``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from hubs.protocols.ur import (
    NORMAL,
    PROTECTIVE_STOP,
    ROBOT_MODES,
    RUNNING,
    RUNTIME_PLAYING,
    RUNTIME_STOPPED,
    SAFETY_MODES,
)
from hubs.sim.ur_kinematics import inverse, tcp_pose
from hubs.sim.ur_rtde_codec import REGISTER, default_value, rtde_type

HOME_Q = [0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0]  # where the fake starts: the model's home


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
        match = REGISTER.match(name)
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
