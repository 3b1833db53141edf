"""Helpers of the deployment tests: run hubctl's operations commands in-process, write a station file."""

from __future__ import annotations

import argparse
import io
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path

from common.config.hubs_toml import StationConfig, load_config
from deploy.remote.cli import register_deploy_commands

REPO = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Run:
    code: int
    out: str
    err: str


def hubctl(*argv: str) -> Run:
    """`hubctl ARGV` with only the commands of deploy/remote/cli.py (independent of cli.py's wiring)."""
    parser = argparse.ArgumentParser(prog="hubctl")
    register_deploy_commands(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(list(argv))
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = int(args.func(args) or 0)
    return Run(code, out.getvalue(), err.getvalue())


def _value(value: object) -> str:
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    return str(value)


def station_toml(base: StationConfig | None = None, *, hosts: dict[str, tuple[str, str]] | None = None,
                 modes: dict[str, str] | None = None, connect: list[str] | None = None, comment: str = "") -> str:
    """The reference station's hubs.toml with every device emulated (no driver parameters), and
    `hosts` {hub: (host, ssh_user)} / `modes` {resource: mode} / `connect` replaced. Written from the
    loaded file, so that the tests follow hubs.toml as it changes."""
    base = base or load_config(REPO / "hubs.toml")
    hosts, modes = hosts or {}, modes or {}
    lines = [f"# {comment}" if comment else "# test station",
             "[station]", f"name = {_value(base.station.name)}", f"model = {_value(base.station.model)}",
             "[network]", f"mode = {_value(base.network.mode)}",
             f"connect = {_value(connect if connect is not None else list(base.network.connect))}",
             f"listen = {_value(list(base.network.listen))}", f"lease_ms = {base.network.lease_ms}",
             "[controller]", f"host = {_value(base.controller.host)}", f"name = {_value(base.controller.name)}"]
    for hub in base.hubs.values():
        host, user = hosts.get(hub.name, (hub.host, hub.ssh_user))
        lines += [f"[hubs.{hub.name}]", f"host = {_value(host)}", f"ssh_user = {_value(user)}"]
        for resource, device in hub.devices.items():
            lines += [f"[hubs.{hub.name}.devices.{resource}]", f"type = {_value(device.type)}",
                      f"mode = {_value(modes.get(resource, 'emulate'))}"]
    return "\n".join(lines) + "\n"
