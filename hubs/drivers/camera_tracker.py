"""Safety camera: operator zone from a people tracker's feed.

There is no standard protocol for person trackers, so statehub defines a small one,
the *tracker feed*: the tracker listens on TCP (default port 7001); a client connects
and receives one UTF-8 JSON object per line, at a fixed rate (10-30 Hz), also when
nobody is in view (the frames are the heartbeat)::

    {"v": 1, "seq": 42, "t": 1712345678.123, "people": [{"id": 1, "x": 2.10, "y": 0.35}]}

``v`` feed version (1), ``seq`` frame counter, ``t`` tracker clock (Unix s, informative),
``people`` the tracked persons with station coordinates in metres.  Clients send
nothing.  A line that is not valid JSON of this shape is ignored and counted.

Zones are axis-aligned rectangles ``[x_min, y_min, x_max, y_max]`` in hubs.toml
(several per zone allowed)::

    zones = { robot = [[0, 0, 2, 2]], shared = [[-1, -1, 3, 3]] }

``zone_m`` is the most restrictive zone any person is in: ``robot`` over ``shared`` over
``outside`` (nobody in a zone, or nobody in view).

Device lost: the connection drops, or no valid frame for ``stale_after`` s (default
0.5; a silence gets one more wait of half that, so that frames that came while the hub's
loop was busy count): ``read`` raises ``DeviceUnavailable`` (never the last zone); the
shared ReconnectLogic reconnects with backoff.  Safe state: none (no outputs).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections.abc import Mapping, Sequence
from typing import Annotated

import msgspec

from common.model import Value
from hubs.drivers.base import DeviceUnavailable, NoOutputs, SelftestReport
from hubs.drivers.params import DriverParams, Port, Positive, invalid
from hubs.drivers.reconnect import Backoff, LinkedDriver, ReconnectLogic, describe
from hubs.drivers.registry import DriverPlugin
from hubs.protocols.tracker_feed import DEFAULT_PORT, VERSION

log = logging.getLogger(__name__)

Rect = tuple[float, float, float, float]
ZONE_ORDER = ("robot", "shared")  # most restrictive first; anything else is "outside"


def parse_rects(zones: Mapping[str, Sequence[Sequence[float]]]) -> dict[str, list[Rect]]:
    out: dict[str, list[Rect]] = {}
    for name, rects in zones.items():
        if name not in ZONE_ORDER:
            raise ValueError(f"unknown zone {name!r}; zones are {', '.join(ZONE_ORDER)}")
        parsed = []
        for rect in rects:
            if len(rect) != 4:
                raise ValueError(f"zone {name}: a rectangle is [x_min, y_min, x_max, y_max], got {rect!r}")
            x0, y0, x1, y1 = (float(v) for v in rect)
            parsed.append((min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1)))
        out[name] = parsed
    return out


def zone_of(x: float, y: float, zones: Mapping[str, list[Rect]]) -> str:
    for name in ZONE_ORDER:
        for x0, y0, x1, y1 in zones.get(name, ()):
            if x0 <= x <= x1 and y0 <= y <= y1:
                return name
    return "outside"


def parse_frame(line: bytes) -> list[tuple[float, float]]:
    """The people positions in a feed line; ValueError when it is not a version-1 frame."""
    try:
        obj = json.loads(line)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"not JSON: {exc}") from exc
    if not isinstance(obj, dict) or obj.get("v") != VERSION or not isinstance(obj.get("people"), list):
        raise ValueError("not a version-1 tracker frame")
    people = []
    for person in obj["people"]:
        try:
            people.append((float(person["x"]), float(person["y"])))
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"bad person entry {person!r}") from exc
    return people


class CameraTracker(NoOutputs, LinkedDriver[ReconnectLogic]):
    def __init__(
        self,
        resource: str = "cam",
        *,
        host: str,
        port: int = DEFAULT_PORT,
        zones: Mapping[str, Sequence[Sequence[float]]],
        stale_after: float = 0.5,
        backoff: Backoff | None = None,
    ) -> None:
        self.resource = resource
        self.host = host
        self.port = port
        self.zones = parse_rects(zones)
        self.stale_after = stale_after
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._task: asyncio.Task[None] | None = None
        self._people: list[tuple[float, float]] = []
        self._frame_time = 0.0
        self._first_frame = asyncio.Event()
        self.stats = {"frames": 0, "bad_frames": 0}
        self._link = ReconnectLogic(
            f"{resource}@{host}:{port}", self._open, self._release, backoff=backoff, connect_timeout=2 * stale_after + 1
        )

    async def read(self) -> Mapping[str, Value]:
        people = await self._fresh_people()
        zones = {zone_of(x, y, self.zones) for x, y in people}
        zone = next((z for z in ZONE_ORDER if z in zones), "outside")
        return {"zone_m": zone}

    async def selftest(self) -> SelftestReport:
        report = SelftestReport(self.resource)
        if not await self._link.wait_attempt():
            report.add("device answers", False, f"no tracker feed at {self.host}:{self.port}: {self._link.last_error}")
            report.add("inputs read", False, "not checked: device absent")
            return report
        report.add("device answers", True, f"tracker feed at {self.host}:{self.port}")
        try:
            values = await self.read()
            report.add("inputs read", True, f"zone_m={values['zone_m']}, {len(self._people)} in view, {self.stats}")
        except DeviceUnavailable as exc:
            report.add("inputs read", False, str(exc))
        report.add("outputs read back", True, "not applicable: the camera has no outputs")
        return report

    async def _fresh_people(self) -> list[tuple[float, float]]:
        """The people of the latest frame, if the tracker is alive.

        Frames are stamped when the event loop takes them: after the loop was busy (a long GC, a
        starved process) the frames that came meanwhile still wait in the socket, so a frame that
        looks old gets one short wait for them before the tracker is declared lost."""
        if not self.connected:
            raise DeviceUnavailable(f"{self.resource}: tracker not connected ({self._link.last_error})")
        if time.monotonic() - self._frame_time > self.stale_after:
            await asyncio.sleep(self.stale_after / 2)
        age = time.monotonic() - self._frame_time
        if age > self.stale_after:
            reason = f"no tracker frame for {age:.2f} s"
            self._link.connection_lost(reason)
            raise DeviceUnavailable(f"{self.resource}: {reason}")
        return self._people

    async def _receive(self, reader: asyncio.StreamReader) -> None:
        try:
            while True:
                line = await self._next_line(reader)
                if line is None:
                    self._link.connection_lost(f"no tracker frame for {self.stale_after} s")
                    return
                if not line:
                    self._link.connection_lost("tracker closed the connection")
                    return
                try:
                    people = parse_frame(line)
                except ValueError as exc:
                    self.stats["bad_frames"] += 1
                    log.debug("%s: bad frame ignored: %s", self.resource, exc)
                    continue
                self._people, self._frame_time = people, time.monotonic()
                self.stats["frames"] += 1
                self._first_frame.set()
        except (ConnectionError, OSError, asyncio.LimitOverrunError, ValueError) as exc:
            self._link.connection_lost(f"feed read failed: {describe(exc)}")

    async def _next_line(self, reader: asyncio.StreamReader) -> bytes | None:
        """The next line, or None when the tracker is silent.  A timeout that fires as the loop comes
        back from being busy may beat the lines that wait in the socket: they get one short wait."""
        for wait in (self.stale_after, self.stale_after / 2):
            try:
                async with asyncio.timeout(wait):
                    return await reader.readline()
            except TimeoutError:
                continue
        return None

    async def _open(self) -> None:
        self._first_frame.clear()
        self._frame_time = 0.0
        reader, writer = await asyncio.open_connection(self.host, self.port, limit=1 << 16)
        self._reader, self._writer = reader, writer
        self._task = asyncio.create_task(self._receive(reader), name=f"feed:{self.resource}")
        try:
            async with asyncio.timeout(2 * self.stale_after):
                await self._first_frame.wait()
        except TimeoutError:
            raise ConnectionError("connected, but no tracker frame arrived") from None

    async def _release(self) -> None:
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        writer, self._writer = self._writer, None
        if writer is not None:
            writer.close()
            with contextlib.suppress(Exception):
                async with asyncio.timeout(1.0):
                    await writer.wait_closed()
        self._reader = None


Rectangle = Annotated[list[float], msgspec.Meta(min_length=4, max_length=4)]  # [x_min, y_min, x_max, y_max]


class CameraParams(DriverParams, frozen=True, kw_only=True):
    host: str
    port: Port = DEFAULT_PORT
    zones: dict[str, list[Rectangle]]
    stale_after: Positive = 0.5

    def __post_init__(self) -> None:
        for name in self.zones:
            if name not in ZONE_ORDER:
                raise invalid(f"zones.{name}", f"unknown zone {name!r}; zones are {', '.join(ZONE_ORDER)}")


def build(resource: str, params: CameraParams) -> CameraTracker:
    return CameraTracker(resource, host=params.host, port=params.port, zones=params.zones,
                         stale_after=params.stale_after, backoff=params.backoff())


PLUGIN = DriverPlugin(CameraParams, build)
