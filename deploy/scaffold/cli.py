"""`hubctl new-station NAME` and `hubctl new-device TYPE` (docs/new-station.md)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

from common.config.hubs_toml import ConfigError

from .files import ScaffoldError


def cmd_new_station(args: argparse.Namespace) -> int:
    from .station import new_station

    return _report(lambda: new_station(args.name, Path(args.dir) if args.dir else None))


def cmd_new_device(args: argparse.Namespace) -> int:
    from .device import new_device

    return _report(lambda: new_device(args.type, Path(args.station), force=args.force))


def _report(command: Callable[[], list[str]]) -> int:
    try:
        lines = command()
    except (ScaffoldError, ConfigError) as exc:
        print(f"hubctl: {exc}", file=sys.stderr)
        return 2
    print("\n".join(lines))
    return 0


def register_scaffold_commands(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add `new-station` and `new-device` to hubctl's subcommands (deploy/cli.py build_parser)."""
    station = sub.add_parser("new-station", help="make a station project (a Python package: model, hubs.toml, tests) "
                                                 "that runs as it is, every device emulated")
    station.add_argument("name", help="the station's name, also its Python package's (e.g. pick_cell)")
    station.add_argument("--dir", help="where to write it (default: ./NAME; must be empty or new)")
    station.set_defaults(func=cmd_new_station)
    device = sub.add_parser("new-device", help="a driver skeleton for a device type of the station's model (its "
                                               "variable contract, typed parameters, entry point, hubs.toml entry) "
                                               "and its model-based test")
    device.add_argument("type", help="the device type, e.g. gripper (a stub model is added if the model has none)")
    device.add_argument("--station", default=".", help="the station project's directory (default: .)")
    device.add_argument("--force", action="store_true", help="overwrite the driver and test written before")
    device.set_defaults(func=cmd_new_device)
