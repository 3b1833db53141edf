"""The router process: `hubctl router --config line.toml --name R` (what its systemd unit runs).

It opens the router session, says READY=1 to systemd once it serves, feeds the watchdog from its
loop, logs the routers and peers it links to as they come and go, and closes the session on
SIGTERM or SIGINT (exit 0). A bad line.toml or a missing certificate is one line and exit 2, as
for the hubs and the controller.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
from pathlib import Path

import zenoh

from common.config.errors import ConfigError
from common.config.security import SecurityError
from common.line.config import LineConfig, load_line
from common.plumbing.lifecycle import setup_logging, stop_on_signals
from common.plumbing.sdnotify import Notifier

from .config import describe, line_router_config
from .security import router_tls

log = logging.getLogger("statehub.router")
LINK_LOG_PERIOD_S = 1.0


def _neighbours(session: zenoh.Session) -> tuple[set[str], set[str]]:
    info = session.info
    return {str(z) for z in info.routers_zid()}, {str(z) for z in info.peers_zid()}


async def serve(line: LineConfig, name: str, certs: Path | None = None) -> int:
    tls = router_tls(line, name, certs)
    config = line_router_config(line, name, tls)
    stop = stop_on_signals()
    notifier = Notifier()
    router = line.routers[name]
    session = await asyncio.to_thread(zenoh.open, config)
    try:
        log.info("router %s of line %s (zid %s): %s; %s", name, line.name, session.info.zid(),
                 describe({"listen": router.listen, "connect": router.connect}),
                 "TLS with the site's CA, access control on" if tls is not None else "INSECURE: plain TCP")
        notifier.ready()
        routers: set[str] = set()
        peers: set[str] = set()
        while not stop.is_set():
            notifier.alive()
            now_routers, now_peers = _neighbours(session)
            for zid in sorted(now_routers - routers):
                log.info("router %s linked", zid)
            for zid in sorted(routers - now_routers):
                log.warning("router %s gone", zid)
            if now_peers != peers:
                log.info("peers: %d", len(now_peers))
            routers, peers = now_routers, now_peers
            try:
                async with asyncio.timeout(LINK_LOG_PERIOD_S):
                    await stop.wait()
            except TimeoutError:
                pass
        log.info("router %s stopping", name)
    finally:
        await asyncio.to_thread(session.close)
        notifier.close()
    return 0


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="hubctl router", description="run a Zenoh router of the line")
    add_arguments(p)
    return p


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", default="line.toml", help="the site's line.toml (default: ./line.toml)")
    p.add_argument("--name", help="which router of its [routers] (default: the only one)")
    p.add_argument("--certs", help="with [security] mode = \"tls\": this router's certificate directory "
                                   "(default: [security] certs)")
    p.add_argument("-v", "--verbose", action="store_true")


def run(args: argparse.Namespace) -> int:
    setup_logging(f"router-{args.name or ''}".rstrip("-"), args.verbose)
    try:
        line = load_line(args.config)
        name = args.name
        if name is None:
            if len(line.routers) != 1:
                raise KeyError(f"{args.config}: {len(line.routers)} routers ({', '.join(line.routers)}): "
                               f"say which with --name")
            name = next(iter(line.routers))
        if name not in line.routers:
            raise KeyError(f"{args.config}: no router {name!r} (routers: {', '.join(line.routers)})")
        return asyncio.run(serve(line, name, Path(args.certs) if args.certs else None))
    except (ConfigError, SecurityError, FileNotFoundError) as exc:
        print(f"router: {exc}", file=sys.stderr)
        return 2
    except KeyError as exc:
        print(f"router: {exc.args[0]}", file=sys.stderr)
        return 2


def main(argv: list[str] | None = None) -> int:
    return run(parser().parse_args(argv))
