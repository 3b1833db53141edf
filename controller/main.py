"""The controller process: `python -m controller --config hubs.toml` runs the station's controller over Zenoh.

What its systemd unit runs, and `hubctl up`; `hubctl controller` is the same command.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from common.config.hubs_toml import load_station
from common.config.modes import Execution, argument
from common.config.production import plan_from_options
from common.plumbing.lifecycle import EXPECTED_ERRORS, network, positive, run_main, setup_logging, stop_on_signals
from controller.recording.schema import RunMeta, RunMode


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of the controller process (`python -m controller`, `hubctl controller`)."""
    parser.add_argument("--config", default="hubs.toml", help="the station's hubs.toml (default: ./hubs.toml)")
    parser.add_argument("--db", help="SQLite file of the persisted state (default: [controller] db)")
    parser.add_argument("--fresh", action="store_true", help="forget the persisted state first")
    parser.add_argument("--mirror-wait", type=positive, default=5.0, help="seconds to wait for the hubs' mirrors")
    parser.add_argument("--loopback-port", type=int, help="run on loopback, listening on this port")
    parser.add_argument("--certs", metavar="DIR", help="the certificate directory ([security] mode = \"tls\"; "
                                                       "default: [security] certs)")
    parser.add_argument("--hold", action="store_true",
                        help="with no persisted requests, start no operation: the operator starts them from the "
                             "console")
    parser.add_argument("--no-record", action="store_true",
                        help="do not record the run (default: into [controller.recording] dir, see `hubctl replay`)")
    # Set by `hubctl up`: what the recording says about the run.
    parser.add_argument("--run-mode", type=argument(RunMode), choices=(RunMode.SERVICE, RunMode.UP),
                        default=RunMode.SERVICE, help=argparse.SUPPRESS)
    parser.add_argument("--run-seed", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--orders", type=int, metavar="N",
                        help="on a fresh start, queue N orders (default: [production] of hubs.toml, if any)")
    parser.add_argument("--mix", metavar="VARIANT:WEIGHT,...", help="with --orders: the variants, repeating")
    parser.add_argument("--execution", type=argument(Execution), choices=list(Execution),
                        help="how a plan's steps wait for each other (default: [controller] execution)")
    parser.add_argument("--speed", type=positive, default=1.0,
                        help="the emulated devices run this many times faster than their durations (hubctl up "
                             "--speed): the plans' predicted finish, the cycle's bound and the timed checks too")
    parser.add_argument("-v", "--verbose", action="store_true")


async def run_controller(config_path: str, *, loopback_port: int | None = None, db: str | None = None,
                         fresh: bool = False, mirror_wait_s: float = 5.0, hold: bool = False,
                         certs: str | None = None, record: RunMeta | None = None, orders: int | None = None,
                         mix: str | None = None, execution: Execution | None = None, speed: float = 1.0) -> int:
    from common.bus.station_net import security_banner, station_zenoh_config
    from common.bus.zenoh_bus import ZenohBus
    from common.config.security import identity_of
    from controller.service import ControllerService

    config, model = load_station(config_path)
    production = plan_from_options(orders, mix, config.production, model, config_path)
    db_path = db or config.controller.db
    if fresh:
        for suffix in ("", "-wal", "-shm"):
            Path(db_path + suffix).unlink(missing_ok=True)
    zconfig = station_zenoh_config(config, model, identity_of(config, "controller"),
                                   network(config, "controller", loopback_port), certs=certs)
    stop = stop_on_signals()
    async with ZenohBus(zconfig) as bus:
        service = ControllerService(config, model, bus, db=db_path, mirror_wait_s=mirror_wait_s, hold=hold,
                                    record=record, production=production, execution=execution, speed=speed)
        log = logging.getLogger("statehub.controller")
        log.info("controller %s: station %s, %d resources, %d operations, plans run in %s; %s",
                 service.controller_id, config.station.name, len(service.hubs_of), len(model.operations),
                 service.core.engine.execution, security_banner(config))
        if service.recorder.path is not None:
            log.info("recording the run into %s", service.recorder.path)
        await service.run(stop)
    return 0


def serve(args: argparse.Namespace) -> int:
    """Run the controller the options of `add_arguments` describe, until SIGINT or SIGTERM."""
    from controller.station_hold import EXIT_CONFLICT, ControllerConflict

    setup_logging("controller", args.verbose)
    record = None if args.no_record else RunMeta(mode=args.run_mode, seed=args.run_seed)
    try:
        return asyncio.run(run_controller(args.config, loopback_port=args.loopback_port, db=args.db,
                                          fresh=args.fresh, mirror_wait_s=args.mirror_wait, hold=args.hold,
                                          certs=args.certs, record=record, orders=args.orders, mix=args.mix,
                                          execution=args.execution, speed=args.speed))
    except ControllerConflict as exc:
        print(f"controller: {exc}", file=sys.stderr)
        return EXIT_CONFLICT


def main(argv: Sequence[str] | None = None) -> int:
    from controller.synthesis import SynthesisError

    parser = argparse.ArgumentParser(prog="python -m controller", description=__doc__.splitlines()[0])
    add_arguments(parser)
    args = parser.parse_args(argv)
    return run_main("controller", lambda: serve(args), (*EXPECTED_ERRORS, SynthesisError))
