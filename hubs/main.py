"""A hub process: `python -m hubs HUB --config hubs.toml` serves the hub's devices over Zenoh.

What its systemd unit runs, and `hubctl up` once per hub; `hubctl hub` is the same command.
`--selftest` runs the hub's self-test instead (the unit's ExecStartPre, `hubctl selftest`):
it prints the report and exits 1 on a failure.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from common.config.hubs_toml import load_station
from common.config.modes import DeviceMode, argument
from common.plumbing.lifecycle import network, positive, run_main, setup_logging, stop_on_signals


def parse_failures(items: Sequence[str]) -> dict[str, float]:
    """`--failure RESOURCE=P` options: the probability of each emulated device's alternative outcome."""
    result = {}
    for item in items:
        resource, _, value = item.partition("=")
        try:
            p = float(value)
        except ValueError:
            message = f"--failure {item!r}: expected RESOURCE=PROBABILITY, e.g. nr=0.1"
            raise argparse.ArgumentTypeError(message) from None
        if not 0.0 <= p <= 1.0:
            raise argparse.ArgumentTypeError(f"--failure {item!r}: the probability must be within 0..1")
        result[resource] = p
    return result


def parameter_overrides(params_file: str | None) -> dict[str, dict[str, Any]] | None:
    """The --params-file: {resource: {parameter: value}}, merged into hubs.toml's."""
    if not params_file:
        return None
    from hubs.factory import load_overrides

    try:
        return load_overrides(params_file)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_selftest_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of a hub's self-test: which hub of which hubs.toml, its devices' modes and parameters."""
    parser.add_argument("name", help="the hub, e.g. pi-tool")
    parser.add_argument("--config", default="hubs.toml", help="the station's hubs.toml (default: ./hubs.toml)")
    parser.add_argument("--mode", type=argument(DeviceMode), choices=list(DeviceMode),
                        help="override every device's mode")
    parser.add_argument("--real", action="append", default=[], metavar="RESOURCE",
                        help="run this device in mode real, whatever hubs.toml or --mode says (repeatable)")
    parser.add_argument("--params-file", metavar="FILE",
                        help="driver parameter overrides, JSON or .toml: {resource: {parameter: value}}")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of a hub process (`python -m hubs`, `hubctl hub`)."""
    add_selftest_arguments(parser)
    parser.add_argument("--speed", type=positive, default=1.0, help="scale emulated delays")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--failure", action="append", default=[], metavar="RESOURCE=P")
    parser.add_argument("--loopback-port", type=int, help="run on loopback, the controller listening on this port")
    parser.add_argument("--certs", metavar="DIR", help="the certificate directory ([security] mode = \"tls\"; "
                                                       "default: [security] certs)")
    parser.add_argument("--emulated-state", metavar="DIR", type=Path,
                        help="where emulated devices keep their values, so that a restarted hub finds its devices "
                             "as it left them (hubctl up gives its run directory's)")
    parser.add_argument("--selftest", action="store_true",
                        help="run the hub's self-test instead of serving; exit 1 on a failure")
    parser.add_argument("-v", "--verbose", action="store_true")


async def run_hub(config_path: str, hub: str, *, loopback_port: int | None = None, speed: float = 1.0,
                  seed: int = 0, mode: DeviceMode | None = None, failure: dict[str, float] | None = None,
                  overrides: Mapping[str, Mapping[str, Any]] | None = None, certs: str | None = None,
                  real: Sequence[str] = (), emulated_state: Path | None = None) -> int:
    from common.bus.station_net import security_banner, station_zenoh_config
    from common.bus.zenoh_bus import ZenohBus
    from common.config.security import identity_of
    from hubs.factory import build_drivers
    from hubs.runtime import HubRuntime

    config, model = load_station(config_path)
    settings = config.hubs.get(hub)
    if settings is None:
        raise argparse.ArgumentTypeError(f"{config.path}: no hub named {hub!r} (hubs: {', '.join(config.hubs)})")
    drivers = build_drivers(config, hub, model, speed=speed, seed=seed, mode=mode, failure=failure,
                            overrides=overrides, certs=certs, real=real, emulated_state=emulated_state)
    zconfig = station_zenoh_config(config, model, identity_of(config, hub), network(config, hub, loopback_port),
                                   certs=certs)
    stop = stop_on_signals()
    async with ZenohBus(zconfig) as bus:
        runtime = HubRuntime(hub=hub, station=config.station.name, model=model, drivers=drivers, bus=bus,
                             rate_hz=settings.rate_hz, command_timeout_s=settings.command_timeout_s)
        logging.getLogger("statehub.hub").info("hub %s serving %s; %s", hub, ", ".join(drivers),
                                               security_banner(config))
        await runtime.run(stop)
    return 0


async def run_selftest(config_path: str, hub: str, *, mode: DeviceMode | None = None,
                       overrides: Mapping[str, Mapping[str, Any]] | None = None, real: Sequence[str] = ()) -> int:
    from common.wire.selftest_report import format_report
    from hubs.factory import build_drivers
    from hubs.selftest import run_selftest as selftest

    config, model = load_station(config_path)
    drivers = build_drivers(config, hub, model, mode=mode, overrides=overrides, real=real)
    report = await selftest(hub, drivers)
    print(format_report(report))
    return 0 if report.ok else 1


def selftest(args: argparse.Namespace) -> int:
    """Run the self-test the options of `add_selftest_arguments` describe."""
    return asyncio.run(run_selftest(args.config, args.name, mode=args.mode,
                                    overrides=parameter_overrides(args.params_file), real=args.real))


def serve(args: argparse.Namespace) -> int:
    """Run the hub the options of `add_arguments` describe, until SIGINT or SIGTERM."""
    if args.selftest:
        return selftest(args)
    failure, overrides = parse_failures(args.failure), parameter_overrides(args.params_file)
    setup_logging(args.name, args.verbose)
    return asyncio.run(run_hub(args.config, args.name, loopback_port=args.loopback_port, speed=args.speed,
                               seed=args.seed, mode=args.mode, failure=failure, overrides=overrides,
                               certs=args.certs, real=args.real, emulated_state=args.emulated_state))


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hubs", description=__doc__.splitlines()[0])
    add_arguments(parser)
    args = parser.parse_args(argv)
    return run_main(f"hub {args.name}", lambda: serve(args))
