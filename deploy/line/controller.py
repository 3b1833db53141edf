"""The line controller: `hubctl line controller --config line.toml` (also `python -m deploy.line.controller`).

It owns the line's products and hands each from station to station along the route (handover.py), a
round every ROUND_S, persisted in [line] db (store.py). It is a client of [line] router and talks to the
stations only through their order keys (`{station}/ctl/orders`). `--products N` on a fresh start (a db
without products) puts N products at the head of the route. It runs until SIGTERM/SIGINT, saying READY=1
and feeding systemd's watchdog like the hubs and the station controllers.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from common.bus.protocol import Bus
from common.bus.zenoh_bus import ZenohBus
from common.bus.zenoh_config import ZenohConfig, zenoh_config
from common.config.errors import ConfigError
from common.config.hubs_toml import load_config
from common.config.modes import NetworkMode
from common.config.security import SecurityError
from common.line.config import LineConfig, load_line
from common.plumbing.lifecycle import exit_process, setup_logging, stop_on_signals
from common.plumbing.sdnotify import Notifier
from common.wire.keys import Keys
from common.wire.messages import MessageError, decode, encode
from common.wire.orders import ORDERS_KEY, OrdersReply, OrdersRequest

from .handover import Handover
from .store import LineStore

log = logging.getLogger("statehub.line")
ROUND_S = 0.5
ASK_TIMEOUT_S = 2.0
MAX_PRODUCTS = 10_000


def product_ids(line: LineConfig, count: int) -> list[str]:
    return [f"{line.name}-{i:05d}" for i in range(1, count + 1)]


def station_keys(line: LineConfig) -> dict[str, Keys]:
    """Each station's keys, by its line name: its hubs.toml's [station] name."""
    return {name: load_config(station.config).keys for name, station in line.stations.items()}


class BusLink:
    """The stations' order keys over the line controller's bus."""

    def __init__(self, bus: Bus, keys: dict[str, Keys], timeout: float = ASK_TIMEOUT_S) -> None:
        self.bus = bus
        self.keys = keys
        self.timeout = timeout

    async def ask(self, station: str, request: OrdersRequest) -> OrdersReply | None:
        replies = await self.bus.get(self.keys[station].ctl(ORDERS_KEY), payload=encode(request),
                                     timeout=self.timeout)
        for reply in replies:
            if not reply.ok:
                continue
            try:
                return decode(reply.payload, OrdersReply)
            except MessageError as exc:
                log.warning("unreadable reply from %s: %s", station, exc)
        return None


def line_zenoh_config(line: LineConfig, certs: Path | None = None) -> ZenohConfig:
    """A client of [line] router; with [security] mode = "tls" presenting the line controller's certificate."""
    from .security import line_controller_tls

    tls = line_controller_tls(line, certs)
    endpoints = line.router_endpoints(line.router)
    return zenoh_config(NetworkMode.CLIENT, connect=endpoints, lease_ms=line.lease_ms, tls=tls)


def open_store(line: LineConfig, *, fresh: bool, products: int | None) -> LineStore:
    if fresh:
        for suffix in ("", "-wal", "-shm"):
            Path(str(line.db) + suffix).unlink(missing_ok=True)
    store = LineStore(line.db)
    if products is not None and store.empty():
        route = [(name, line.stations[name].variant) for name in line.route]
        store.add_products(product_ids(line, products), route)
        log.info("%d products at the head of the route %s", products, " -> ".join(line.route))
    return store


async def run_line_controller(line: LineConfig, *, fresh: bool = False, products: int | None = None,
                              certs: Path | None = None) -> int:
    store = open_store(line, fresh=fresh, products=products)
    stop = stop_on_signals()
    notifier = Notifier()
    last = len(line.route) - 1
    reported_done = -1
    try:
        async with ZenohBus(line_zenoh_config(line, certs)) as bus:
            handover = Handover(store, BusLink(bus, station_keys(line)))
            log.info("line controller of %s: %d stations (%s), a client of router %s", line.name, len(line.route),
                     " -> ".join(line.route), line.router)
            notifier.ready()
            while not stop.is_set():
                notifier.alive()
                await handover.round()
                done, total = store.products_left(last)
                if done != reported_done:
                    log.info("%d/%d products left the last station", done, total)
                    reported_done = done
                try:
                    async with asyncio.timeout(ROUND_S):
                        await stop.wait()
                except TimeoutError:
                    pass
    finally:
        store.close()
        notifier.close()
    return 0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", default="line.toml", help="the line's line.toml (default: ./line.toml)")
    p.add_argument("--products", type=int, metavar="N", help="on a fresh start, N products at the head of the route")
    p.add_argument("--fresh", action="store_true", help="forget [line] db: start with no product")
    p.add_argument("--certs", help="with [security] mode = \"tls\": the line controller's certificate directory")
    p.add_argument("-v", "--verbose", action="store_true")


def run(args: argparse.Namespace) -> int:
    setup_logging("line-controller", args.verbose)
    try:
        if args.products is not None and not 1 <= args.products <= MAX_PRODUCTS:
            raise ValueError(f"--products {args.products}: give 1 to {MAX_PRODUCTS}")
        line = load_line(args.config)
        return asyncio.run(run_line_controller(line, fresh=args.fresh, products=args.products,
                                               certs=Path(args.certs) if args.certs else None))
    except (ConfigError, SecurityError, FileNotFoundError, ValueError) as exc:
        print(f"line controller: {exc}", file=sys.stderr)
        return 2


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m deploy.line.controller", description=__doc__.splitlines()[0])
    add_arguments(p)
    return run(p.parse_args(argv))


if __name__ == "__main__":
    exit_process(main())
