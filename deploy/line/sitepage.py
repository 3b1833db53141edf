"""The line's overview as a web page (controller/overview/site.py's site view): served by `hubctl line up`
beside its printed overview, and by `hubctl line overview --config line.toml` on its own, beside a running
line (it follows every station's status through its routers and the line controller's SQLite read-only)."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import sys
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path

from aiohttp import web

from common.config.errors import ConfigError
from common.config.overview import BindAddress, parse_bind
from common.config.security import SecurityError
from common.line.config import load_line
from common.plumbing.lifecycle import setup_logging, stop_on_signals
from controller.overview.site import SiteFeed, make_site_app

from .overview import Overview, site_picture

DEFAULT_BIND = "127.0.0.1:8471"
STREAMS_CLOSE_S = 1.0  # open event streams (every browser showing the page) end at once on exit
REFRESH_S = 0.25


@contextlib.asynccontextmanager
async def served(feed: SiteFeed, bind: str, say: Callable[[str], object]) -> AsyncIterator[str | None]:
    """Serve the site view on `bind` (port 0: any free port) while inside; yields its URL, or None (and says
    why) when it cannot listen there: the line runs on without its page."""
    address = _bind_address(bind)
    runner = web.AppRunner(make_site_app(feed), handle_signals=False, shutdown_timeout=STREAMS_CLOSE_S)
    await runner.setup()
    url: str | None = None
    try:
        try:
            await web.TCPSite(runner, address.host, address.port).start()
            port = int(runner.addresses[0][1])
            url = BindAddress(address.host, port).url()
        except OSError as exc:
            say(f"  overview page: cannot serve on {bind}: {exc.strerror or exc} (--overview-bind another "
                f"HOST:PORT)")
        yield url
    finally:
        await runner.cleanup()


def _bind_address(text: str) -> BindAddress:
    """parse_bind's HOST:PORT, and HOST:0 for any free port (tests, several lines on one machine)."""
    host, _, port = text.rpartition(":")
    return BindAddress(host.strip("[]"), 0) if host and port == "0" else parse_bind(text)


async def run_line_overview(config: str, bind: str, certs: Path | None = None,
                            say: Callable[[str], object] = print) -> int:
    from .up import StationWatch, progress

    line = load_line(config)
    overview = Overview(line.route)
    feed = SiteFeed(line.name)
    watch = StationWatch(line, overview, time.monotonic, certs)
    stop = stop_on_signals()
    async with served(feed, bind, say) as url:
        if url is None:
            return 2
        say(f"overview of line {line.name}: {url} (read-only; {len(line.route)} stations)")
        watchers = [asyncio.create_task(watch.follow(router, stop)) for router in line.routers]
        try:
            while not stop.is_set():
                _first, last, total = progress(line.db, len(line.route))
                await feed.update(site_picture(line.name, overview.rows(time.monotonic()), last, total))
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(REFRESH_S):
                        await stop.wait()
        finally:
            for task in watchers:
                task.cancel()
            await asyncio.gather(*watchers, return_exceptions=True)
    return 0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", default="line.toml", help="the line's line.toml (default: ./line.toml)")
    p.add_argument("--bind", default=DEFAULT_BIND, metavar="HOST:PORT",
                   help=f"where the page is served (default {DEFAULT_BIND}; 0.0.0.0:PORT for every interface)")
    p.add_argument("--certs", help="with [security] mode = \"tls\": the line controller's certificate directory, "
                                   "whose certificate may read every station's status")
    p.add_argument("-v", "--verbose", action="store_true")


def run(args: argparse.Namespace) -> int:
    setup_logging("line-overview", args.verbose)
    try:
        return asyncio.run(run_line_overview(args.config, args.bind, Path(args.certs) if args.certs else None))
    except (ConfigError, SecurityError, ValueError) as exc:
        print(f"line overview: {exc}", file=sys.stderr)
        return 2
