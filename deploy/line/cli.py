"""`hubctl line controller|up`: registered on hubctl's parser (deploy/cli.py)."""

from __future__ import annotations

import argparse
from pathlib import Path

from . import controller, sitepage
from .up import RUN_DIR, LineOptions, line_up


def cmd_line_up(args: argparse.Namespace) -> int:
    return line_up(LineOptions(config=args.config, products=args.products, run_dir=Path(args.run_dir),
                               time_limit=args.time_limit, record=not args.no_record,
                               overview_bind=None if args.no_overview_page else args.overview_bind))


def register_line_commands(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    line = sub.add_parser("line", help="a line of stations over Zenoh routers (line.toml)")
    commands = line.add_subparsers(dest="line_command", required=True)
    ctl = commands.add_parser("controller", help="run the line controller: it hands the products from station to "
                                                 "station")
    controller.add_arguments(ctl)
    ctl.set_defaults(func=controller.run)
    up = commands.add_parser("up", help="run the whole line on this machine: routers, stations, line controller; "
                                        "print the overview; end when every product left the last station")
    up.add_argument("--config", default="line.toml", help="the line's line.toml (default: ./line.toml)")
    up.add_argument("--products", type=int, default=5, metavar="N", help="products through the line (default 5)")
    up.add_argument("--run-dir", default=str(RUN_DIR), help=f"logs and state (default {RUN_DIR})")
    up.add_argument("--time-limit", type=float, default=900.0, metavar="S", help="give up after S seconds")
    up.add_argument("--no-record", action="store_true", help="the stations do not record their runs")
    up.add_argument("--overview-bind", default=sitepage.DEFAULT_BIND, metavar="HOST:PORT",
                    help=f"where the overview's web page is served (default {sitepage.DEFAULT_BIND})")
    up.add_argument("--no-overview-page", action="store_true", help="print the overview only, serve no page")
    up.set_defaults(func=cmd_line_up)
    page = commands.add_parser("overview", help="serve the overview of a running line as a web page (read-only): "
                                                "every station's state, product, cycle, health, unreachable")
    sitepage.add_arguments(page)
    page.set_defaults(func=sitepage.run)
