"""A simulated safety-camera tracker serving the statehub tracker feed (TCP, JSON lines).

The feed (documented with the driver in ``hubs/drivers/camera_tracker.py``): the tracker
listens; every client receives one JSON object per line at ``rate`` Hz, also when nobody
is in view::

    {"v": 1, "seq": 42, "t": 1712345678.123, "people": [{"id": 1, "x": 2.10, "y": 0.35}]}

Positions are station coordinates in metres.  In-process: ``CameraTrackerSim``
(``await start()``, ``set_person``, ``remove_person``, ``freeze`` a hung tracker that
keeps the connection but sends nothing, ``stop``/``start`` on the same port).  As a
process: ``python -m hubs.sim.camera_tracker --port 7001 [--walk]`` prints
``listening on HOST:PORT``; ``--walk [SPEED]`` moves one operator back and forth along y = 1 m
from x = -2 to x = 4 at SPEED m/s (0.5) so that a station run sees all zones; ``--control``
reads the people in view from stdin instead, one JSON object per line (what the simulated
world of ``deploy/local/simworld.py`` sends as its operator walks)::

    {"person": 1, "x": 1.0, "y": 3.0}      # person 1 is (now) at x, y
    {"person": 1, "remove": true}          # person 1 left the view

Bad lines are reported on stderr and ignored.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import sys
import time
from typing import Any

from hubs.protocols.tracker_feed import DEFAULT_PORT, VERSION
from hubs.sim.registry import SimServer, SimulatedDevice, SimulatorPlugin, python_module, tcp_params


class CameraTrackerSim:
    def __init__(self, host: str = "127.0.0.1", port: int = 0, rate: float = 20.0) -> None:
        self.host = host
        self.port = port
        self.rate = rate
        self.people: dict[int, tuple[float, float]] = {}
        self.frozen = False
        self.seq = 0
        self._server: asyncio.Server | None = None
        self._writers: set[asyncio.StreamWriter] = set()
        self._ticker: asyncio.Task[None] | None = None

    def set_person(self, person_id: int, x: float, y: float) -> None:
        self.people[person_id] = (x, y)

    def remove_person(self, person_id: int) -> None:
        self.people.pop(person_id, None)

    def freeze(self, frozen: bool = True) -> None:
        """A hung tracker: connections stay open, no frames."""
        self.frozen = frozen

    def frame(self) -> bytes:
        self.seq += 1
        people = [{"id": i, "x": round(x, 3), "y": round(y, 3)} for i, (x, y) in sorted(self.people.items())]
        frame = {"v": VERSION, "seq": self.seq, "t": round(time.time(), 3), "people": people}
        return (json.dumps(frame) + "\n").encode()

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._writers.add(writer)
        try:
            await reader.read()  # clients do not talk; returns at EOF
        except (ConnectionError, OSError):
            pass
        finally:
            self._writers.discard(writer)
            writer.close()

    async def _tick(self) -> None:
        while True:
            await asyncio.sleep(1.0 / self.rate)
            if self.frozen or not self._writers:
                continue
            data = self.frame()
            for writer in list(self._writers):
                try:
                    writer.write(data)
                except (ConnectionError, OSError, RuntimeError):
                    self._writers.discard(writer)

    async def start(self) -> int:
        if self._server is not None:
            return self.port
        self._server = await asyncio.start_server(self._client, self.host, self.port, reuse_address=True)
        self.port = self._server.sockets[0].getsockname()[1]
        self._ticker = asyncio.create_task(self._tick())
        return self.port

    async def stop(self) -> None:
        """The tracker vanishes: connections dropped, nothing listens."""
        ticker, self._ticker = self._ticker, None
        if ticker is not None:
            ticker.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await ticker
        server, self._server = self._server, None
        if server is not None:
            server.close()
        for writer in list(self._writers):
            writer.close()
        self._writers.clear()
        if server is not None:
            await server.wait_closed()

    @property
    def running(self) -> bool:
        return self._server is not None


def apply_control(sim: CameraTrackerSim, line: str) -> str | None:
    """One ``--control`` line applied to ``sim``; the problem with it, or None."""
    try:
        request = json.loads(line)
        person = int(request["person"])
        if request.get("remove"):
            sim.remove_person(person)
        else:
            sim.set_person(person, float(request["x"]), float(request["y"]))
    except (ValueError, KeyError, TypeError) as exc:
        return f"ignored control line {line.strip()!r}: {type(exc).__name__}: {exc}"
    return None


async def _follow_stdin(sim: CameraTrackerSim) -> None:
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    while line := await reader.readline():
        if line.strip():
            problem = apply_control(sim, line.decode(errors="replace"))
            if problem:
                print(problem, file=sys.stderr, flush=True)


async def _serve(host: str, port: int, rate: float, walk: float, control: bool = False) -> None:
    sim = CameraTrackerSim(host, port, rate)
    bound = await sim.start()
    print(f"listening on {host}:{bound}", flush=True)
    try:
        if control:
            await _follow_stdin(sim)  # returns when stdin closes: the world is gone
            return
        start = time.monotonic()
        while True:
            if walk:  # triangle wave between x = -2 and x = 4
                phase = ((time.monotonic() - start) * walk) % 12.0
                sim.set_person(1, -2.0 + (phase if phase < 6.0 else 12.0 - phase), 1.0)
            await asyncio.sleep(0.05 if walk else 3600)
    finally:
        await sim.stop()


# --- as a simulator plugin (device type camera) ------------------------------------------------

SIM_ZONES = {"shared": [[0.0, 0.0, 2.0, 2.0]], "robot": [[2.0, 0.0, 4.0, 2.0]]}  # where the world's operator walks


def _server(device: SimulatedDevice) -> SimServer:
    zones: Any = device.params.get("zones", SIM_ZONES)
    return SimServer(python_module("hubs.sim.camera_tracker", "--host", "127.0.0.1", "--port", "0", "--control"),
                     driver_params=lambda address: {**tcp_params(address), "zones": zones}, control=True)


PLUGIN = SimulatorPlugin("camera tracker feed", server=_server,
                         defaults={"host": "127.0.0.1", "port": DEFAULT_PORT, "zones": SIM_ZONES})


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Simulated safety-camera tracker feed (TCP JSON lines)")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT, help="TCP port (0: any free port)")
    parser.add_argument("--rate", type=float, default=20.0, help="frames per second")
    parser.add_argument(
        "--walk",
        type=float,
        nargs="?",
        const=0.5,
        default=0.0,
        metavar="SPEED",
        help="one operator walking through all zones (m/s, default 0.5)",
    )
    parser.add_argument("--control", action="store_true", help="read the people in view from stdin (JSON lines)")
    args = parser.parse_args(argv)
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(_serve(args.host, args.port, args.rate, args.walk, args.control))
    return 0


if __name__ == "__main__":
    sys.exit(main())
