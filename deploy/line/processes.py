"""The processes of a line on one machine, as `Child`ren of deploy/local/supervisor.py: the routers, each
station's controller and hubs (clients of their router, as their hubs.toml says), the line controller.

A station's processes are those `hubctl up` runs, started from its own hubs.toml rather than on loopback:
`[network] mode = "client"` there makes every one a client of its router. A station controller runs with
`--hold`: it requests nothing of its own, only the orders the line controller adds.
"""

from __future__ import annotations

import sys
from pathlib import Path

from common.config.hubs_toml import load_config
from common.line.config import LineConfig, LineStation
from deploy.local.supervisor import Child

PYTHON = sys.executable


def router_child(line: LineConfig, router: str, run_dir: Path, certs: Path | None = None) -> Child:
    argv = [PYTHON, "-m", "deploy.router", "--config", str(line.path), "--name", router]
    if certs is not None:
        argv += ["--certs", str(certs)]
    return Child(f"router {router}", argv, run_dir / f"router-{router}.log")


def station_children(station: LineStation, run_dir: Path, *, record: bool = False,
                     certs: Path | None = None) -> list[Child]:
    """The station's controller (first) and hubs; their logs and the controller's SQLite in run_dir/NAME/."""
    config = load_config(station.config)
    folder = run_dir / station.name
    secured = ["--certs", str(certs)] if certs is not None else []
    controller = [PYTHON, "-m", "controller", "--config", str(station.config), "--db",
                  str(folder / "controller.sqlite"), "--hold", *secured]
    controller += ["--run-mode", "up"] if record else ["--no-record"]
    children = [Child(f"{station.name} controller", controller, folder / "controller.log",
                      first_start_args=["--fresh"])]
    for hub in config.hubs:
        children.append(Child(f"{station.name} {hub}", [PYTHON, "-m", "hubs", hub, "--config", str(station.config),
                                                         *secured], folder / f"{hub}.log"))
    return children


def line_controller_child(line: LineConfig, run_dir: Path, products: int | None,
                          certs: Path | None = None) -> Child:
    argv = [PYTHON, "-m", "deploy.line.controller", "--config", str(line.path)]
    if certs is not None:
        argv += ["--certs", str(certs)]
    first = ["--fresh"] + (["--products", str(products)] if products is not None else [])
    return Child("line controller", argv, run_dir / "line-controller.log", first_start_args=first)
