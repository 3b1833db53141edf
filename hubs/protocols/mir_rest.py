"""The MiR100 REST API v2.0.0: base path, robot states, and its Basic authentication.

Shared by the driver (`hubs.drivers.mir_rest`) and the simulator (`hubs.sim.mir_rest`).
"""

from __future__ import annotations

import base64
import hashlib

API = "/api/v2.0.0"
READY, PAUSE, EXECUTING, EMERGENCY_STOP = 3, 4, 5, 10  # `state_id` of GET/PUT /status
STATE_TEXT = {READY: "Ready", PAUSE: "Pause", EXECUTING: "Executing", EMERGENCY_STOP: "EmergencyStop"}


def auth_header(username: str, password: str) -> str:
    """`Authorization` as the robot expects it: Basic base64(username:sha256hex(password))."""
    token = f"{username}:{hashlib.sha256(password.encode()).hexdigest()}"
    return "Basic " + base64.b64encode(token.encode()).decode()
