"""RTDE wire format, as far as the fake UR controller speaks it: message types, data types, recipes.

Every message is ``uint16 size (header included) | uint8 type | payload``, big-endian.
Output and input recipes name variables; the fake gives *every* name a type: the official
RTDE type of a known name, INT32/DOUBLE/BOOL for registers by name pattern, DOUBLE otherwise.
"""

from __future__ import annotations

import re
import struct
from typing import Any

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
REGISTER = re.compile(r"^(input|output)_(bit|int|double)_register_(\d+)$")


def rtde_type(name: str) -> str:
    """The RTDE type of a variable; permissive: unknown names are DOUBLE."""
    if name in OUTPUT_TYPES:
        return OUTPUT_TYPES[name]
    match = REGISTER.match(name)
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
