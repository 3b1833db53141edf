"""`hubctl line up --config line.toml [--products N]`: the whole line on this machine.

Every router, every station's controller and hubs (clients of their router, as their hubs.toml says) and
the line controller run as separate processes, restarted as their units would restart them
(deploy/local/supervisor.py; the routers with ROUTER_RESTART). This process watches every station's
`ctl/status` through a client session per router, prints a line when a station's state, product or health
changes and the whole overview every `overview_every_s` (overview.py), reads the line controller's SQLite
for the products that left the last station, and ends when every product did; then it checks from each
station's recordings that every operation of every product was done once there (deploy/local/done_once.py).
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from common.bus.zenoh_bus import ZenohBus
from common.bus.zenoh_config import zenoh_config
from common.config.hubs_toml import load_config
from common.config.modes import NetworkMode
from common.line.config import LineConfig, load_line
from common.wire.keys import Keys
from common.wire.messages import MessageError
from controller.console.statusview import StatusFollower
from controller.overview.site import SiteFeed
from deploy.local.done_once import DoneOnce, check_done_once, run_recordings
from deploy.local.supervisor import Say, Supervisor
from deploy.remote.restart_policy import UP_RESTART, RestartPolicy

from .certs import line_certs
from .overview import Overview, StationRow, StationState, overview_text, site_picture
from .processes import line_controller_child, router_child, station_children
from .security import line_controller_tls
from .sitepage import DEFAULT_BIND, served
from .store import VisitState, open_read_only

RUN_DIR = Path("var/line")
# A router comes back after a few seconds, as its unit's RestartSec would bring it back.
ROUTER_RESTART = RestartPolicy(delay_s=5.0)
OVERVIEW_SETTLE_S = 3.0


@dataclass(frozen=True)
class Kill:
    """Kill `process` (SIGKILL; a name of the run's processes: "router r2", "line controller", "s2 controller")
    once `after_products` products left the first station; it restarts as its unit would restart it."""

    process: str
    after_products: int


@dataclass
class LineOptions:
    config: str = "line.toml"
    products: int = 5
    run_dir: Path = RUN_DIR
    time_limit: float = 900.0
    overview_every_s: float = 10.0
    record: bool = True
    kills: tuple[Kill, ...] = ()
    overview_bind: str | None = DEFAULT_BIND  # the overview's web page (port 0: any free one); None: no page


@dataclass
class LineResult:
    finished: bool
    products_done: int
    products: int
    elapsed_s: float
    done_once: dict[str, DoneOnce] = field(default_factory=dict)
    unreachable_seen: dict[str, int] = field(default_factory=dict)  # station -> times it became unreachable
    restarts: dict[str, int] = field(default_factory=dict)
    last_rows: list[StationRow] = field(default_factory=list)  # the overview at the end

    def ok(self) -> bool:
        return self.finished and not any(d.redone() for d in self.done_once.values())


def progress(db: Path, route_length: int) -> tuple[int, int, int]:
    """(products that left the first station, the last one, products): from the line controller's file."""
    if not db.exists():
        return 0, 0, 0
    connection = open_read_only(db)
    try:
        rows = connection.execute("SELECT step, COUNT(*) FROM visits WHERE state=? GROUP BY step",
                                  (VisitState.DONE.value,)).fetchall()
        (total,) = connection.execute("SELECT COUNT(DISTINCT product_id) FROM visits").fetchone()
    except Exception:  # the line controller is creating it
        return 0, 0, 0
    finally:
        connection.close()
    done = {int(step): int(count) for step, count in rows}
    return done.get(0, 0), done.get(route_length - 1, 0), int(total)


class StationWatch:
    """Every station's status through one client session per router."""

    def __init__(self, line: LineConfig, overview: Overview, clock: Callable[[], float],
                 certs: Path | None = None) -> None:
        self.line = line
        self.certs = certs
        self.overview = overview
        self.clock = clock
        self.keys: dict[str, Keys] = {name: load_config(s.config).keys for name, s in line.stations.items()}

    async def follow(self, router: str, stop: asyncio.Event) -> None:
        # With TLS it presents the line controller's certificate: what may read every station's status.
        config = zenoh_config(NetworkMode.CLIENT, connect=self.line.router_endpoints(router),
                              lease_ms=self.line.lease_ms, tls=line_controller_tls(self.line, self.certs))
        while not stop.is_set():
            try:
                async with ZenohBus(config) as bus:
                    await self._read(bus, stop)
            except (OSError, RuntimeError):  # a router that is down: try again
                await asyncio.sleep(1.0)

    async def _read(self, bus: ZenohBus, stop: asyncio.Event) -> None:
        readers = [asyncio.create_task(self._read_station(bus, name, keys)) for name, keys in self.keys.items()]
        try:
            await stop.wait()
        finally:
            for reader in readers:
                reader.cancel()
            await asyncio.gather(*readers, return_exceptions=True)

    async def _read_station(self, bus: ZenohBus, station: str, keys: Keys) -> None:
        follower = StatusFollower(bus, keys)
        statuses = bus.subscribe(keys.ctl("status"), coalesce=False)
        while True:
            sample = await statuses.get()
            try:
                status = await follower.take(sample.payload)
            except MessageError:
                continue
            if status is not None:
                self.overview.take(station, status, self.clock())


async def run_line(options: LineOptions, say: Say = print) -> LineResult:
    line = load_line(options.config)
    site = SiteFeed(line.name)
    async with contextlib.AsyncExitStack() as page:
        if options.overview_bind is not None:
            url = await page.enter_async_context(served(site, options.overview_bind, say))
            if url is not None:
                say(f"overview page: {url} (read-only)")
        with line_certs(line) as certs:
            return await _run_line(options, say, line, certs, site)


async def _run_line(options: LineOptions, say: Say, line: LineConfig, certs: Path | None,
                    site: SiteFeed) -> LineResult:
    run_dir = options.run_dir
    began, began_wall = time.monotonic(), time.time()
    station_children_all = [c for name in line.route
                            for c in station_children(line.stations[name], run_dir, record=options.record, certs=certs)]
    routers = Supervisor([router_child(line, r, run_dir, certs) for r in line.routers], ROUTER_RESTART, say)
    processes = Supervisor([*station_children_all, line_controller_child(line, run_dir, options.products, certs)],
                           UP_RESTART, say)
    say(f"statehub line up: line {line.name}, {len(line.route)} stations ({' -> '.join(line.route)}), "
        f"{len(line.routers)} routers, {options.products} products; logs in {run_dir}/")
    say("  links: mutual TLS with the site's certificates, access control at the routers" if certs is not None
        else "  links: INSECURE plain TCP (line.toml [security] mode = \"insecure\"): for one machine only")
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    overview = Overview(line.route)
    watch = StationWatch(line, overview, time.monotonic, certs)
    result = LineResult(False, 0, options.products, 0.0)
    headlines: dict[str, tuple[object, ...]] = {}
    await routers.start()
    await processes.start()
    watchers = [asyncio.create_task(watch.follow(r, stop), name=f"watch {r}") for r in line.routers]
    kills = list(options.kills)
    next_overview = time.monotonic() + options.overview_every_s
    try:
        while not stop.is_set():
            now = time.monotonic()
            elapsed = now - began
            first, last, total = progress(line.db, len(line.route))
            result.products_done, result.products = last, total or options.products
            await site.update(site_picture(line.name, overview.rows(now), last, result.products))
            for row in overview.rows(now):
                _report_change(row, headlines, result, elapsed, say)
            if total and last == total:
                result.finished = True
                await _settle(overview, total)
                break
            gave_up = routers.gave_up or processes.gave_up
            if gave_up:
                say(gave_up.message())
                break
            for kill in [k for k in kills if first >= k.after_products]:
                kills.remove(kill)
                supervisor = routers if kill.process in routers.children else processes
                pid = supervisor.kill(kill.process)
                say(f"     run {elapsed:6.1f}s  KILLED {kill.process} (pid {pid})")
            if now >= next_overview:
                say(overview_text(overview.rows(now), last, total, elapsed))
                next_overview = now + options.overview_every_s
            if elapsed > options.time_limit:
                say(f"time limit of {options.time_limit:.0f} s reached")
                break
            await asyncio.sleep(0.25)
    finally:
        stop.set()
        for task in watchers:
            task.cancel()
        for task in watchers:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        await processes.stop()
        await routers.stop()
    result.elapsed_s = time.monotonic() - began
    result.restarts = {**routers.restarts, **processes.restarts}
    result.last_rows = overview.rows(time.monotonic())
    await site.update(site_picture(line.name, result.last_rows, result.products_done, result.products))
    say(overview_text(result.last_rows, result.products_done, result.products, result.elapsed_s))
    say(f"{'finished' if result.finished else 'NOT finished'}: {result.products_done}/{result.products} products "
        f"left the last station in {result.elapsed_s:.1f} s; restarts: "
        + (", ".join(f"{n} {c}" for n, c in result.restarts.items() if c) or "none"))
    if options.record:
        for name in line.route:
            station = line.stations[name]
            config = load_config(station.config)
            recordings = run_recordings(str(station.config), config.station.name, began_wall - 1.0)
            result.done_once[name] = check_done_once(recordings)
            say(f"  {name}: {result.done_once[name].text()}")
    return result


async def _settle(overview: Overview, products: int, within_s: float = OVERVIEW_SETTLE_S) -> None:
    """Let the stations' last statuses reach the overview: the line controller may learn from an order list
    that the last product left before the station's next status says so."""
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline and any(r.done < products for r in overview.rows(time.monotonic())):
        await asyncio.sleep(0.1)


def _report_change(row: StationRow, headlines: dict[str, tuple[object, ...]], result: LineResult, elapsed: float,
                   say: Say) -> None:
    headline = row.headline()
    before = headlines.get(row.station)
    if before == headline:
        return
    headlines[row.station] = headline
    if row.state is StationState.UNREACHABLE:
        result.unreachable_seen[row.station] = result.unreachable_seen.get(row.station, 0) + 1
    say(f"     run {elapsed:6.1f}s  {row.text().strip()}")


def line_up(options: LineOptions, say: Say = print) -> int:
    result = asyncio.run(run_line(options, say))
    return 0 if result.ok() else 1
