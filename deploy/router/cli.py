"""`hubctl router`: registered on hubctl's parser (deploy/cli.py)."""

from __future__ import annotations

import argparse

from .main import add_arguments, run


def register_router_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    router = sub.add_parser("router", help="run a Zenoh router of the line (what its systemd unit runs: "
                                           "python -m deploy.router)")
    add_arguments(router)
    router.set_defaults(func=run)
