"""The UR worker process: the only place ur-rtde runs.

ur-rtde's calls block while holding the GIL (a silent peer freezes the interpreter) and
its destructors may abort the process on exit, so the hub never imports it.  The
driver (``hubs.drivers.ur_rtde``) starts this module's ``run`` in a process of its own
(``multiprocessing``, spawn) and talks to it over a pipe; it kills and restarts the
worker when it fails or falls silent.  The worker leaves with ``os._exit``, so no
ur-rtde destructor runs.

Pipe protocol (plain tuples, pickled by ``multiprocessing.Connection``):

driver → worker::

    ("move", id, kind, values)   kind "joint" (6 joint angles, rad) or "tcp" (x y z rx ry rz)
    ("stop", id)                 motion backend stop, then dashboard "stop"
    ("unlock", id)               dashboard "close safety popup", "unlock protective stop"
    ("dashboard", id, text)      one dashboard command, the reply line comes back
    ("quit",)

worker → driver::

    ("ready", info)              RTDE receive, dashboard and motion backend are up
    ("error", text)              start-up failed; the worker exits
    ("state", snapshot)          every ``publish_period``: timestamp, q, qd, tcp, target_q,
                                 robot_mode, safety_mode, protective_stop, runtime_state,
                                 rtde_connected
    ("reply", id, ok, detail)

Motion is behind ``MotionBackend``: ``RtdeControlMotion`` is the real one
(``RTDEControlInterface.moveJ/moveL(..., asynchronous=True)``, ``stopJ``);
``SideChannelMotion`` commands the fake controller (``hubs.sim.ur_rtde_fake``) through
its JSON-lines command port.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import socket
import threading
import time
import traceback
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any, Protocol

from hubs.protocols.ur import COMMAND_PORT, DASHBOARD_PORT

RECEIVE_VARIABLES = [
    "timestamp",
    "actual_q",
    "actual_qd",
    "target_q",
    "actual_TCP_pose",
    "robot_mode",
    "safety_mode",
    "safety_status_bits",
    "robot_status_bits",
    "runtime_state",
]


@dataclass(frozen=True)
class WorkerConfig:
    host: str
    backend: str = "real"  # "real": RTDEControlInterface; "sim": the fake's command port
    command_port: int = COMMAND_PORT
    dashboard_port: int = DASHBOARD_PORT
    frequency: float = 125.0
    publish_period: float = 0.02
    joint_speed: float = 1.05  # rad/s, leading axis
    joint_acceleration: float = 1.4  # rad/s²
    tcp_speed: float = 0.25  # m/s
    tcp_acceleration: float = 1.2  # m/s²


class MotionBackend(Protocol):
    """Starts and stops motion; ``move`` returns as soon as the motion has started."""

    def move(self, kind: str, values: list[float]) -> None: ...
    def stop(self) -> None: ...
    def program_stopped(self) -> None: ...  # the dashboard stopped the robot program
    def close(self) -> None: ...


class RtdeControlMotion:
    """The real backend: ur-rtde's RTDEControlInterface (uploads its control script)."""

    def __init__(self, config: WorkerConfig) -> None:
        import rtde_control

        self.config = config
        self._control = rtde_control.RTDEControlInterface(config.host, config.frequency)
        self._stopped = False

    def program_stopped(self) -> None:
        self._stopped = True

    def _ensure_script(self) -> None:
        # Stopped by the dashboard or a protective stop: upload the control script again.  After a
        # dashboard stop the status bits lag a few RTDE cycles: wait until they show it, or ur-rtde
        # would send the command to a script that no longer runs.
        if self._stopped:
            deadline = time.monotonic() + 1.0
            while self._control.isProgramRunning() and time.monotonic() < deadline:
                time.sleep(0.01)
            self._stopped = False
        if self._control.isProgramRunning():
            return
        if not self._control.reuploadScript():
            raise RuntimeError("could not start the ur-rtde control script")
        deadline = time.monotonic() + 2.0  # the RTDE status bits follow a few cycles later
        while not self._control.isProgramRunning():
            if time.monotonic() > deadline:
                raise RuntimeError("ur-rtde control script uploaded but not running")
            time.sleep(0.01)

    def move(self, kind: str, values: list[float]) -> None:
        self._ensure_script()
        c = self.config
        if kind == "joint":
            ok = self._control.moveJ(values, c.joint_speed, c.joint_acceleration, True)
        else:
            ok = self._control.moveL(values, c.tcp_speed, c.tcp_acceleration, True)
        if not ok:
            raise RuntimeError(f"{'moveJ' if kind == 'joint' else 'moveL'} was not accepted")

    def stop(self) -> None:
        if self._control.isProgramRunning():
            self._control.stopJ(2.0, False)

    def close(self) -> None:
        try:
            self._control.stopScript()
        finally:
            self._control.disconnect()


class SideChannelMotion:
    """The simulated backend: the fake controller's command port (JSON lines)."""

    def __init__(self, config: WorkerConfig) -> None:
        self.config = config
        self._sock = socket.create_connection((config.host, config.command_port), timeout=2.0)
        self._file = self._sock.makefile("rw", encoding="utf-8", newline="\n")

    def _call(self, request: dict[str, Any]) -> dict[str, Any]:
        self._file.write(json.dumps(request) + "\n")
        self._file.flush()
        line = self._file.readline()
        if not line:
            raise ConnectionError("command port closed")
        reply: dict[str, Any] = json.loads(line)
        if not reply.get("ok"):
            raise RuntimeError(str(reply.get("error", "refused")))
        return reply

    def move(self, kind: str, values: list[float]) -> None:
        c = self.config
        if kind == "joint":
            self._call({"cmd": "movej", "q": values, "speed": c.joint_speed})
        else:
            self._call({"cmd": "movel", "pose": values, "speed": c.tcp_speed})

    def stop(self) -> None:
        self._call({"cmd": "stop"})

    def program_stopped(self) -> None:
        pass

    def close(self) -> None:
        self._sock.close()


def make_backend(config: WorkerConfig) -> MotionBackend:
    if config.backend == "real":
        return RtdeControlMotion(config)
    if config.backend == "sim":
        return SideChannelMotion(config)
    raise ValueError(f"unknown motion backend {config.backend!r} (real or sim)")


def _describe(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"


def _dashboard_line(dashboard: Any, text: str) -> str:
    dashboard.send(text + "\n")
    return str(dashboard.receive()).strip()


def run(conn: Connection, config: WorkerConfig) -> None:
    """Worker main: never returns (``os._exit``)."""
    try:
        import dashboard_client
        import rtde_receive

        receive = rtde_receive.RTDEReceiveInterface(config.host, config.frequency, RECEIVE_VARIABLES)
        dashboard = dashboard_client.DashboardClient(config.host, config.dashboard_port)
        dashboard.connect(2000)
        version = _dashboard_line(dashboard, "PolyscopeVersion")
        remote = _dashboard_line(dashboard, "is in remote control")
        backend = make_backend(config)
    except BaseException as exc:  # report anything, then leave without destructors
        try:
            conn.send(("error", _describe(exc)))
        finally:
            os._exit(2)
    send_lock = threading.Lock()

    def send(msg: tuple[Any, ...]) -> None:
        with send_lock:
            conn.send(msg)

    # Requests run in a thread of their own, so that the state keeps flowing while a command
    # blocks (a script upload, a dashboard round trip); ur-rtde releases the GIL while it waits.
    requests: queue.Queue[tuple[Any, ...] | None] = queue.Queue()

    def serve_requests() -> None:
        while (request := requests.get()) is not None:
            try:
                send(_handle(request, backend, dashboard))
            except (EOFError, OSError):
                return

    commands = threading.Thread(target=serve_requests, name="ur-commands", daemon=True)
    commands.start()
    send(("ready", {"polyscope": version, "remote_control": remote, "backend": config.backend}))
    next_publish = time.monotonic()
    try:
        while True:
            if conn.poll(max(0.0, next_publish - time.monotonic())):
                request = conn.recv()
                if request[0] == "quit":
                    break
                requests.put(request)
            now = time.monotonic()
            if now >= next_publish:
                send(("state", _snapshot(receive)))
                next_publish = max(next_publish + config.publish_period, now)
    except (EOFError, OSError):
        pass  # the driver went away
    except BaseException:
        traceback.print_exc()
    requests.put(None)
    commands.join(1.0)
    with contextlib.suppress(BaseException):
        backend.close()
    os._exit(0)


def _snapshot(receive: Any) -> dict[str, Any]:
    return {
        "timestamp": receive.getTimestamp(),
        "q": list(receive.getActualQ()),
        "qd": list(receive.getActualQd()),
        "target_q": list(receive.getTargetQ()),
        "tcp": list(receive.getActualTCPPose()),
        "robot_mode": int(receive.getRobotMode()),
        "safety_mode": int(receive.getSafetyMode()),
        "protective_stop": bool(receive.isProtectiveStopped()),
        "runtime_state": int(receive.getRuntimeState()),
        "rtde_connected": bool(receive.isConnected()),
    }


def _handle(request: tuple[Any, ...], backend: MotionBackend, dashboard: Any) -> tuple[Any, ...]:
    kind, req_id = request[0], request[1]
    try:
        if kind == "move":
            backend.move(request[2], [float(v) for v in request[3]])
            return ("reply", req_id, True, "moving")
        if kind == "stop":
            problems = []
            try:
                backend.stop()
            except Exception as exc:
                problems.append(f"backend stop: {_describe(exc)}")
            reply = _dashboard_line(dashboard, "stop")
            backend.program_stopped()
            return ("reply", req_id, not problems or reply == "Stopped", "; ".join([*problems, reply]))
        if kind == "unlock":
            _dashboard_line(dashboard, "close safety popup")
            reply = _dashboard_line(dashboard, "unlock protective stop")
            return ("reply", req_id, reply.startswith("Protective stop releasing"), reply)
        if kind == "dashboard":
            return ("reply", req_id, True, _dashboard_line(dashboard, str(request[2])))
        return ("reply", req_id, False, f"unknown request {kind!r}")
    except Exception as exc:
        return ("reply", req_id, False, _describe(exc))
