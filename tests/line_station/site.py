"""A test line on this machine: line.toml, two routers and N copies of the line station's hubs.toml.

Each station gets a name unique to the run (runs on one machine never hear each other), holder names
prefixed with its line name (`s1-ctl`, `s1-pi-tool`: certificate names are unique on a line), the
endpoint of its router and its own recordings' directory (`s1/runs`); stations alternate between the
routers so that handovers cross both.
"""

from __future__ import annotations

import os
import uuid
from pathlib import Path

from common.plumbing.lifecycle import free_port

TEMPLATE = Path(__file__).with_name("hubs.toml")
ROUTERS = ("r1", "r2")


def station_toml(name: str, prefix: str, router_endpoint: str, runs: Path, *, tls: bool = False) -> str:
    text = TEMPLATE.read_text()
    replacements = [
        ("stale_after_s = 1.0", f'stale_after_s = 1.0\n\n[controller.recording]\ndir = "{runs}"'),
        ('name = "line_station"', f'name = "{name}"'),
        ('name = "ctl"', f'name = "{prefix}-ctl"'),
        ('connect = ["tcp/127.0.0.1:7501"]', f'connect = ["{router_endpoint}"]'),
        ('operators = ["operator"]', f'operators = ["{prefix}-operator"]' + (
            '\nmode = "tls"\nverify_names = false' if tls else "")),
        ("[hubs.pi-tool", f"[hubs.{prefix}-pi-tool"),
        ("[hubs.ur10", f"[hubs.{prefix}-ur10"),
    ]
    for old, new in replacements:
        assert old in text, old
        text = text.replace(old, new)
    return text + f'\n[overview]\nname = "{prefix}-overview"\n'  # the viewer's certificate, unique on the line too


def write_line(directory: Path, stations: int = 3, *, tls: bool = False) -> Path:
    """line.toml and its stations' hubs.toml under `directory`; returns line.toml's path."""
    run = f"{os.getpid()}_{uuid.uuid4().hex[:6]}"
    ports = {router: free_port() for router in ROUTERS}
    scheme = "tls" if tls else "tcp"
    endpoint = {router: f"{scheme}/127.0.0.1:{port}" for router, port in ports.items()}
    lines = [f'[line]\nname = "line_{run}"\ndb = "line.sqlite"\nrouter = "{ROUTERS[0]}"\nlease_ms = 1000\n']
    if tls:
        lines.append('[security]\nmode = "tls"\ncerts = "certs"\n')
    lines.append(f'[routers.{ROUTERS[0]}]\nlisten = ["{endpoint[ROUTERS[0]]}"]\n')
    lines.append(f'[routers.{ROUTERS[1]}]\nlisten = ["{endpoint[ROUTERS[1]]}"]\nconnect = ["{endpoint[ROUTERS[0]]}"]\n')
    names = [f"s{i + 1}" for i in range(stations)]
    for index, name in enumerate(names):
        router = ROUTERS[index % len(ROUTERS)]
        folder = directory / name
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "hubs.toml").write_text(
            station_toml(f"{name}_{run}", name, endpoint[router], folder / "runs", tls=tls))
        lines.append(f'[stations.{name}]\nconfig = "{name}/hubs.toml"\nrouter = "{router}"\n')
    lines.append("[route]\nstations = [" + ", ".join(f'"{n}"' for n in names) + "]\n")
    path = directory / "line.toml"
    path.write_text("\n".join(lines))
    return path
