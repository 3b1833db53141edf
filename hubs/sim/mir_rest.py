"""A simulated MiR100 REST API (v2.0.0 subset) on aiohttp.

Endpoints (all under ``/api/v2.0.0``, all requiring ``Authorization: Basic
base64(user:sha256hex(password))`` like the robot):

* ``GET /status``: ``state_id``, ``state_text``, ``mission_text``, ``position`` {x, y,
  orientation}, ``mission_queue_id``, ``battery_percentage``, ``robot_name``, ``errors``
* ``PUT /status`` {"state_id": 3 | 4}: 3 Ready (continue), 4 Pause
* ``GET /missions``: the missions known to the robot (guid, name)
* ``GET /mission_queue``, ``POST /mission_queue`` {"mission_id": guid} → 201 {id, ...},
  ``DELETE /mission_queue`` → 204 (aborts the running and pending missions),
  ``GET /mission_queue/{id}``

Physics: a *move* mission drives the robot in a straight line to the mission's target
at ``speed`` m/s while the robot is Ready/Executing; Pause stops it where it is.
States: 3 Ready, 4 Pause, 5 Executing, 10 EmergencyStop.  Evaluated lazily from the
clock on every request.

Runs in-process (``MirServer``, ``await start()``; ``stop()``/``start()`` make the robot
vanish and return on the same port; ``restart_robot()`` also empties the queue, like a
reboot) or as a process: ``python -m hubs.sim.mir_rest --port 8080`` (prints
``listening on HOST:PORT``).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from aiohttp import web

from hubs.protocols.mir_rest import API, EMERGENCY_STOP, EXECUTING, PAUSE, READY, STATE_TEXT, auth_header
from hubs.sim.registry import SimServer, SimulatedDevice, SimulatorPlugin, python_module, tcp_params

KITTING_MISSION, KITTING_POSITION = "b9f4a0c2-5d1e-4a7e-9d3b-0c1a2b3c4d01", (2.0, 10.0)
STATION_MISSION, STATION_POSITION = "b9f4a0c2-5d1e-4a7e-9d3b-0c1a2b3c4d02", (20.0, 10.0)
DEFAULT_MISSIONS = {
    KITTING_MISSION: ("Go to kitting", KITTING_POSITION),
    STATION_MISSION: ("Go to station", STATION_POSITION),
}


@dataclass
class QueueEntry:
    id: int
    mission_id: str
    state: str = "Pending"  # Pending, Executing, Done, Aborted


@dataclass
class MirRobot:
    missions: dict[str, tuple[str, tuple[float, float]]] = field(default_factory=lambda: dict(DEFAULT_MISSIONS))
    x: float = 2.0
    y: float = 10.0
    orientation: float = 0.0
    speed: float = 1.0
    state_id: int = READY
    queue: list[QueueEntry] = field(default_factory=list)
    clock: Callable[[], float] = time.monotonic
    _next_id: int = 1
    _last: float = 0.0

    def __post_init__(self) -> None:
        self._last = self.clock()

    def current(self) -> QueueEntry | None:
        return next((e for e in self.queue if e.state == "Executing"), None)

    def update(self) -> None:
        now = self.clock()
        dt, self._last = now - self._last, now
        if self.state_id in (PAUSE, EMERGENCY_STOP):
            return
        entry = self.current()
        if entry is None:
            entry = next((e for e in self.queue if e.state == "Pending"), None)
            if entry is None:
                self.state_id = READY
                return
            entry.state = "Executing"
            dt = 0.0
        self.state_id = EXECUTING
        tx, ty = self.missions[entry.mission_id][1]
        dx, dy = tx - self.x, ty - self.y
        dist = math.hypot(dx, dy)
        step = self.speed * dt
        if dist > 1e-9:
            self.orientation = math.degrees(math.atan2(dy, dx))
        if step >= dist:
            self.x, self.y = tx, ty
            entry.state = "Done"
            self.state_id = READY
            self.update()  # the next pending mission starts at once
        else:
            self.x += dx / dist * step
            self.y += dy / dist * step

    def enqueue(self, mission_id: str) -> QueueEntry:
        entry = QueueEntry(self._next_id, mission_id)
        self._next_id += 1
        self.queue.append(entry)
        return entry

    def abort_all(self) -> None:
        for entry in self.queue:
            if entry.state in ("Pending", "Executing"):
                entry.state = "Aborted"
        if self.state_id == EXECUTING:
            self.state_id = READY

    def mission_text(self) -> str:
        entry = self.current()
        if self.state_id == EMERGENCY_STOP:
            return "Emergency stop pressed"
        if entry is None:
            return "Waiting for new missions..."
        name = self.missions[entry.mission_id][0]
        return f"{name}: paused" if self.state_id == PAUSE else f"{name}: moving"

    def status(self) -> dict[str, Any]:
        entry = self.current()
        return {
            "robot_name": "MiR_sim",
            "state_id": self.state_id,
            "state_text": STATE_TEXT.get(self.state_id, "Unknown"),
            "mission_text": self.mission_text(),
            "mission_queue_id": entry.id if entry else None,
            "position": {"x": round(self.x, 4), "y": round(self.y, 4), "orientation": round(self.orientation, 2)},
            "battery_percentage": 87.5,
            "errors": [],
            "mode_id": 7,
            "mode_text": "Mission",
        }


class MirServer:
    def __init__(
        self,
        robot: MirRobot | None = None,
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        username: str = "admin",
        password: str = "admin",
    ) -> None:
        self.robot = robot or MirRobot()
        self.host = host
        self.port = port
        self.expected_auth = auth_header(username, password)
        self.requests: list[tuple[str, str]] = []  # (method, path) of every authorised request
        self.ignore_state_changes = False  # fault: PUT /status is acknowledged but not applied
        self._runner: web.AppRunner | None = None

    # -- handlers -----------------------------------------------------------------------

    @web.middleware
    async def _auth(self, request: web.Request, handler: Callable[[web.Request], Any]) -> web.StreamResponse:
        if request.headers.get("Authorization") != self.expected_auth:
            return web.json_response({"error_code": "401", "error_human": "Unauthorized"}, status=401)
        self.requests.append((request.method, request.path))
        self.robot.update()
        response: web.StreamResponse = await handler(request)
        return response

    async def _get_status(self, request: web.Request) -> web.Response:
        return web.json_response(self.robot.status())

    async def _put_status(self, request: web.Request) -> web.Response:
        body = await request.json()
        state = body.get("state_id")
        robot = self.robot
        if state not in (READY, PAUSE):
            return web.json_response({"error_human": f"state_id {state!r} cannot be set"}, status=400)
        if robot.state_id == EMERGENCY_STOP:
            return web.json_response({"error_human": "emergency stop active"}, status=409)
        if self.ignore_state_changes:
            return web.json_response(robot.status())
        if state == PAUSE:
            robot.state_id = PAUSE
        else:
            robot.state_id = READY
            robot.update()
        return web.json_response(robot.status())

    async def _missions(self, request: web.Request) -> web.Response:
        return web.json_response(
            [{"guid": g, "name": name, "url": f"{API}/missions/{g}"} for g, (name, _) in self.robot.missions.items()]
        )

    def _entry_json(self, entry: QueueEntry) -> dict[str, Any]:
        return {
            "id": entry.id,
            "mission_id": entry.mission_id,
            "state": entry.state,
            "url": f"{API}/mission_queue/{entry.id}",
        }

    async def _get_queue(self, request: web.Request) -> web.Response:
        return web.json_response(
            [{"id": e.id, "state": e.state, "url": f"{API}/mission_queue/{e.id}"} for e in self.robot.queue]
        )

    async def _post_queue(self, request: web.Request) -> web.Response:
        body = await request.json()
        mission_id = body.get("mission_id")
        if mission_id not in self.robot.missions:
            return web.json_response({"error_human": f"mission {mission_id!r} not found"}, status=400)
        entry = self.robot.enqueue(mission_id)
        self.robot.update()
        return web.json_response(self._entry_json(entry), status=201)

    async def _delete_queue(self, request: web.Request) -> web.Response:
        self.robot.abort_all()
        return web.Response(status=204)

    async def _get_entry(self, request: web.Request) -> web.Response:
        wanted = int(request.match_info["id"])
        entry = next((e for e in self.robot.queue if e.id == wanted), None)
        if entry is None:
            return web.json_response({"error_human": "not found"}, status=404)
        return web.json_response(self._entry_json(entry))

    # -- lifecycle ------------------------------------------------------------------------

    def app(self) -> web.Application:
        app = web.Application(middlewares=[self._auth])
        app.router.add_get(f"{API}/status", self._get_status)
        app.router.add_put(f"{API}/status", self._put_status)
        app.router.add_get(f"{API}/missions", self._missions)
        app.router.add_get(f"{API}/mission_queue", self._get_queue)
        app.router.add_post(f"{API}/mission_queue", self._post_queue)
        app.router.add_delete(f"{API}/mission_queue", self._delete_queue)
        app.router.add_get(f"{API}/mission_queue/{{id}}", self._get_entry)
        return app

    async def start(self) -> int:
        if self._runner is not None:
            return self.port
        runner = web.AppRunner(self.app(), handle_signals=False, access_log=None)
        await runner.setup()
        site = web.TCPSite(runner, self.host, self.port, reuse_address=True)
        await site.start()
        self._runner = runner
        if self.port == 0:
            self.port = runner.addresses[0][1]  # (host, port) of the socket it listens on
        return self.port

    async def stop(self) -> None:
        """The robot vanishes from the network."""
        runner, self._runner = self._runner, None
        if runner is not None:
            await runner.cleanup()

    def restart_robot(self) -> None:
        """A reboot: the queue is gone, the robot is Ready where it stands."""
        self.robot.queue.clear()
        self.robot.state_id = READY

    @property
    def running(self) -> bool:
        return self._runner is not None

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}"


async def _serve(host: str, port: int, speed: float) -> None:
    server = MirServer(MirRobot(speed=speed), host=host, port=port)
    bound = await server.start()
    print(f"listening on {host}:{bound}", flush=True)
    try:
        await asyncio.Event().wait()
    finally:
        await server.stop()


# --- as a simulator plugin (device type mir) ------------------------------------------------------

DEFAULT_PORT = 8080
SIM_TARGETS = {  # the simulator's missions and map positions (hubs.toml's are the real robot's)
    "missions": {"kitting": KITTING_MISSION, "station": STATION_MISSION},
    "positions": {"kitting": list(KITTING_POSITION), "station": list(STATION_POSITION)},
}


def _server(device: SimulatedDevice) -> SimServer:
    return SimServer(
        python_module("hubs.sim.mir_rest", "--host", "127.0.0.1", "--port", "0", "--speed", f"{device.speed:g}"),
        driver_params=lambda address: {**tcp_params(address), "username": "admin", "password": "admin",
                                       **SIM_TARGETS})


PLUGIN = SimulatorPlugin("MiR REST API", server=_server,
                         defaults={"host": "127.0.0.1", "port": DEFAULT_PORT, **SIM_TARGETS})


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Simulated MiR100 REST API")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8080, help="TCP port (0: any free port)")
    parser.add_argument("--speed", type=float, default=1.0, help="m/s")
    args = parser.parse_args(argv)
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(_serve(args.host, args.port, args.speed))
    return 0


if __name__ == "__main__":
    sys.exit(main())
