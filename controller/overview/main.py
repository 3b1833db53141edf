"""`hubctl overview` (`python -m controller.overview`): the supervisors' read-only station overview, a web page.

One process with its own Zenoh session that only reads (reader.py; in `tls` mode the `viewer`
certificate of [overview] name, whose access control allows nothing but reading), serving the page
on [overview] bind (default 127.0.0.1:8470) until SIGINT or SIGTERM.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from common.config.modes import NetworkMode
from common.config.overview import BindAddress, parse_bind
from common.plumbing.lifecycle import EXPECTED_ERRORS, exit_process, run_main, setup_logging, stop_on_signals

log = logging.getLogger("statehub.overview")

STREAMS_CLOSE_S = 1.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", default="hubs.toml", help="the station's hubs.toml (default: ./hubs.toml)")
    parser.add_argument("--bind", metavar="HOST:PORT",
                        help="where the page is served (default: [overview] bind, else 127.0.0.1:8470; "
                             "0.0.0.0:8470 for every interface)")
    parser.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                        help="the controller's zenoh endpoint, e.g. tcp/decs.local:7447 (default: its listeners "
                             "in hubs.toml, on this host)")
    parser.add_argument("--certs", metavar="DIR", help="the certificate directory ([security] mode = \"tls\"; "
                                                       "default: [security] certs)")
    parser.add_argument("--recordings", metavar="DIR",
                        help="where the controller records its runs, for the Gantt chart (default: "
                             "[controller.recording] dir)")
    parser.add_argument("-v", "--verbose", action="store_true")


async def run_overview(config_path: str, *, bind: str | None = None, connect: Sequence[str] = (),
                       certs: str | None = None, recordings: str | None = None,
                       started: asyncio.Event | None = None) -> int:
    from aiohttp import web

    from common.bus.station_net import security_banner, station_zenoh_config
    from common.bus.zenoh_bus import ZenohBus
    from common.config.hubs_toml import NetworkConfig, load_station
    from common.config.security import viewer_identity
    from controller.console.station import StationInfo
    from controller.recording.writer import recording_dir

    from .feed import OverviewFeed
    from .reader import StationReader
    from .runfile import RunGantt
    from .web import make_app

    config, model = load_station(config_path)
    try:
        address: BindAddress = parse_bind(bind or config.overview.bind)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"--bind: {exc}" if bind else f"{config_path}: overview.bind: {exc}") from None
    info = StationInfo.from_station(config, model)
    endpoints = list(connect) or list(info.default_connect)
    network = NetworkConfig(mode=NetworkMode.PEER, listen=[], connect=endpoints, lease_ms=info.lease_ms,
                            max_message_bytes=config.network.max_message_bytes)
    zconfig = station_zenoh_config(config, model, viewer_identity(config), network, certs=certs)
    directory = Path(recordings) if recordings else recording_dir(config.controller.recording.dir)
    feed = OverviewFeed(info, RunGantt(directory, info.station, model))
    stop = stop_on_signals()
    async with ZenohBus(zconfig) as bus:
        # Open event streams (every browser showing the page) end at once on exit: nothing of theirs is owed.
        runner = web.AppRunner(make_app(feed), handle_signals=False, shutdown_timeout=STREAMS_CLOSE_S)
        await runner.setup()
        try:
            try:
                await web.TCPSite(runner, address.host, address.port).start()
            except OSError as exc:
                print(f"overview: cannot serve on {address.host}:{address.port}: {exc.strerror or exc} (another "
                      f"overview running? --bind another HOST:PORT)", file=sys.stderr)
                return 2
            print(f"overview of station {info.station}: {address.url()} (read-only; {security_banner(config)}; "
                  f"controller at {', '.join(endpoints) or 'nobody'})", flush=True)
            if started is not None:
                started.set()
            following = asyncio.create_task(feed.run(StationReader(bus, config.keys)))
            stopping = asyncio.create_task(stop.wait())
            done, _ = await asyncio.wait({following, stopping}, return_when=asyncio.FIRST_COMPLETED)
            for task in (following, stopping):
                task.cancel()
            await asyncio.gather(following, stopping, return_exceptions=True)
            failure = following.exception() if following in done else None
            if failure is not None:
                raise failure
        finally:
            await runner.cleanup()
    return 0


def serve(args: argparse.Namespace) -> int:
    setup_logging("overview", args.verbose)
    return asyncio.run(run_overview(args.config, bind=args.bind, connect=args.connect, certs=args.certs,
                                    recordings=args.recordings))


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m controller.overview", description=__doc__.splitlines()[0])
    add_arguments(parser)
    args = parser.parse_args(argv)
    return run_main("overview", lambda: serve(args), EXPECTED_ERRORS)


if __name__ == "__main__":
    exit_process(main())
