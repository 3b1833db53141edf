"""Universal Robots controller: fixed ports, mode numbers, and the named-pose convention.

Shared by the driver (`hubs.drivers.ur_rtde`, `hubs.drivers.ur_rtde_worker`) and the fake
controller (`hubs.sim.ur_rtde_fake`). A pose is either joint angles (rad) or a TCP pose:
x, y, z in m and a rotation vector (axis times angle, rad), as URScript writes them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

RTDE_PORT, DASHBOARD_PORT = 30004, 29999  # fixed by the robot
SCRIPT_PORTS = (30001, 30002, 30003)  # primary, secondary, real-time: URScript in
COMMAND_PORT = 30099  # not a UR port: the fake controller's side channel for simulated motion

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
POWER_OFF, POWER_ON, IDLE, RUNNING = 3, 4, 5, 7
NORMAL, PROTECTIVE_STOP = 1, 3
RUNTIME_STOPPED, RUNTIME_PLAYING = 1, 2

Matrix3 = list[list[float]]


def rotation_matrix(rv: Sequence[float]) -> Matrix3:
    """The rotation matrix of a rotation vector."""
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


def rotation_between(a: Sequence[float], b: Sequence[float]) -> float:
    """The angle (rad) of the rotation from orientation ``a`` to ``b`` (rotation vectors)."""
    ra, rb = rotation_matrix(a), rotation_matrix(b)
    trace = sum(ra[k][i] * rb[k][i] for i in range(3) for k in range(3))  # trace(raᵀ rb)
    return math.acos(max(-1.0, min(1.0, (trace - 1) / 2)))


@dataclass(frozen=True)
class Pose:
    """A named target: joint angles (`kind` "joint") or a TCP pose ("tcp"), six values."""

    kind: str
    values: tuple[float, ...]

    @classmethod
    def parse(cls, name: str, spec: Mapping[str, Sequence[float]]) -> Pose:
        keys = [k for k in ("q", "tcp") if k in spec]
        if len(keys) != 1:
            raise ValueError(f"pose {name!r}: give exactly one of q (joint angles) or tcp (pose)")
        values = tuple(float(v) for v in spec[keys[0]])
        if len(values) != 6:
            raise ValueError(f"pose {name!r}: 6 values needed, got {len(values)}")
        return cls("joint" if keys[0] == "q" else "tcp", values)
