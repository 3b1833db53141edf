"""hubctl's operations commands: `config check`, `units`, `deploy HUB`, `rollback HUB`.

`register_deploy_commands(sub)` adds them to hubctl's sub-command parser (deploy/cli.py).
Each command reports its own problems and returns the exit status: 0 ok, 1 a problem
(an invalid hubs.toml, a failed step).
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING

from common.config.hubs_toml import ConfigError, StationConfig

if TYPE_CHECKING:
    from .deploy import Connection, Waiting

DEFAULT_CONFIG = "hubs.toml"


def _error(command: str, message: str) -> int:
    print(f"hubctl {command}: {message}", file=sys.stderr)
    return 1


# --- config check --------------------------------------------------------------------------------

def summary(config: StationConfig, resources: int, operations: int) -> list[str]:
    net = config.network
    ctl = config.controller
    lines = [
        f"{config.path}: ok",
        f"  station     {config.station.name}: model {config.station.model} ({resources} resources, "
        f"{operations} operations)",
        f"  network     {net.mode}, connect {', '.join(net.connect) or '-'}, lease {net.lease_ms} ms",
        f"  controller  {ctl.name} on {ctl.host}, listen {', '.join(config.network_for('controller').listen) or '-'}",
    ]
    width = max(len(h) for h in config.hubs)
    for hub in config.hubs.values():
        devices = ", ".join(f"{r} ({d.type}, {d.mode})" for r, d in hub.devices.items()) or "no devices"
        lines.append(f"  hub {hub.name:<{width}}  {hub.ssh_user}@{hub.host}: {devices}")
    modes = Counter(d.mode for h in config.hubs.values() for d in h.devices.values())
    lines.append(f"{len(config.hubs)} hubs serve all {sum(modes.values())} resources of the model, one hub each "
                 f"({', '.join(f'{n} {m}' for m, n in sorted(modes.items()))})")
    return lines


def cmd_config_check(args: argparse.Namespace) -> int:
    from common.config.hubs_toml import load_station
    from common.model import ModelError
    from hubs.factory import check_devices

    path = Path(args.config)
    try:
        config, model = load_station(path)
        check_devices(config)  # every device in sim or real mode has a driver that takes its parameters
    except ConfigError as exc:
        return _error("config check", str(exc))
    except ModelError as exc:
        return _error("config check", f"{path}: station.model: the model is invalid: {exc}")
    except OSError as exc:
        return _error("config check", f"cannot read {path}: {exc.strerror or exc}")
    print("\n".join(summary(config, len(model.resources), len(model.operations))))
    return 0


# --- units ----------------------------------------------------------------------------------------

def cmd_units(args: argparse.Namespace) -> int:
    from common.config.hubs_toml import load_config

    from .layout import Layout
    from .units import BACKOFF_SYSTEMD, DEFAULT_SYSTEMD, local_systemd_version, station_units, write_units

    try:
        config = load_config(args.config)
    except ConfigError as exc:
        return _error("units", str(exc))
    except OSError as exc:
        return _error("units", f"cannot read {args.config}: {exc.strerror or exc}")
    version = args.systemd_version or local_systemd_version() or DEFAULT_SYSTEMD
    source = "--systemd-version" if args.systemd_version else "this machine" if local_systemd_version() else "default"
    units = station_units(config, Layout(args.root), version)
    for path in write_units(units, Path(args.out)):
        print(f"wrote {path}")
    backoff = ("restart delay growing 1 s -> 60 s (RestartSteps)" if version >= BACKOFF_SYSTEMD
               else f"restart delay 5 s (RestartSteps needs systemd {BACKOFF_SYSTEMD})")
    print(f"{len(units)} units for systemd {version} ({source}): {backoff}. `hubctl deploy HUB` installs them; "
          f"by hand: copy to /etc/systemd/system, then systemctl daemon-reload && systemctl enable --now UNIT")
    return 0


# --- deploy and rollback -----------------------------------------------------------------------------

def _connection(args: argparse.Namespace) -> tuple[Connection, Waiting]:
    from .deploy import Connection, Waiting

    connection = Connection(ssh_port=args.ssh_port, identity=args.identity, ssh_options=tuple(args.ssh_option),
                            root=args.root, sudo=not args.no_sudo, dry_run=args.dry_run, known_hosts=args.known_hosts,
                            trust_new_host=getattr(args, "trust_new_host", False))
    waiting = Waiting(wait=not args.no_wait, timeout=args.wait_timeout, listen=args.zenoh_listen,
                      connect=tuple(args.zenoh_connect))
    return connection, waiting


def cmd_deploy(args: argparse.Namespace) -> int:
    from .deploy import DeployFailed, DeployOptions, deploy

    connection, waiting = _connection(args)
    options = DeployOptions(config=Path(args.config), hub=args.hub, connection=connection, waiting=waiting,
                            offline_deps=args.offline_deps, wheel=Path(args.wheel) if args.wheel else None,
                            source=Path(args.source) if args.source else None, python=args.python)
    try:
        asyncio.run(deploy(options))
    except DeployFailed as exc:
        return _error("deploy", str(exc))
    print(f"hub {args.hub}: {'dry run done, nothing was changed' if args.dry_run else 'deployed'}")
    return 0


def cmd_rollback(args: argparse.Namespace) -> int:
    from .deploy import DeployFailed
    from .rollback import RollbackOptions, rollback

    connection, waiting = _connection(args)
    options = RollbackOptions(config=Path(args.config), hub=args.hub, to=args.to, connection=connection,
                              waiting=waiting)
    try:
        asyncio.run(rollback(options))
    except DeployFailed as exc:
        return _error("rollback", str(exc))
    print(f"hub {args.hub}: {'dry run done, nothing was changed' if args.dry_run else 'rolled back'}")
    return 0


def _positive(text: str) -> float:
    value = float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text}")
    return value


def _target_options(p: argparse.ArgumentParser) -> None:
    from .hubwait import DEFAULT_LISTEN

    p.add_argument("hub", help="the hub, a [hubs.NAME] of hubs.toml; its `host` and `ssh_user` say where")
    p.add_argument("--config", default=DEFAULT_CONFIG, help="the station's hubs.toml (default: ./hubs.toml)")
    p.add_argument("--dry-run", action="store_true", help="print every step and command, run none")
    ssh = p.add_argument_group("ssh")
    ssh.add_argument("--ssh-port", type=int, help="the target's SSH port (default: ssh's, usually 22)")
    ssh.add_argument("--identity", metavar="FILE", help="SSH private key (default: ssh's, e.g. the agent)")
    ssh.add_argument("--ssh-option", action="append", default=[], metavar="OPT",
                     help="extra `ssh -o` option, e.g. UserKnownHostsFile=FILE (repeatable)")
    ssh.add_argument("--known-hosts", metavar="FILE",
                     help="the station's known host keys (default: known_hosts next to hubs.toml)")
    ssh.add_argument("--root", default="/", metavar="PREFIX",
                     help="install under PREFIX on the target (PREFIX/opt/statehub, PREFIX/etc/systemd/system); "
                          "for tests and image staging. Users, groups and systemctl still act on the target itself")
    ssh.add_argument("--no-sudo", action="store_true",
                     help="run privileged steps as the SSH user (default: `sudo -n` unless it is root)")
    wait = p.add_argument_group("waiting for the hub")
    wait.add_argument("--no-wait", action="store_true",
                      help="do not wait for the hub's liveliness token and self-test report over Zenoh")
    wait.add_argument("--wait-timeout", type=_positive, default=30.0, metavar="S", help="(default: 30)")
    wait.add_argument("--zenoh-listen", default=DEFAULT_LISTEN, metavar="ENDPOINT",
                      help=f"where this machine listens so that the hub can reach it, in peer mode "
                           f"(default: {DEFAULT_LISTEN}, any interface, a free port)")
    wait.add_argument("--zenoh-connect", action="append", default=[], metavar="ENDPOINT",
                      help="zenoh endpoints to connect to (default: the hub's, from hubs.toml)")


def register_deploy_commands(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add `config check`, `units`, `deploy` and `rollback` to hubctl."""
    config = sub.add_parser("config", help="check hubs.toml")
    config_sub = config.add_subparsers(dest="config_command", required=True)
    check = config_sub.add_parser("check", help="validate hubs.toml and check it against the station model; "
                                                "problems name file, line and key (exit 1)")
    check.add_argument("--config", default=DEFAULT_CONFIG, help="the station's hubs.toml (default: ./hubs.toml)")
    check.set_defaults(func=cmd_config_check)

    units = sub.add_parser("units", help="write the systemd unit of the controller and of every hub")
    units.add_argument("--config", default=DEFAULT_CONFIG, help="the station's hubs.toml (default: ./hubs.toml)")
    units.add_argument("--out", default="units", metavar="DIR", help="where to write them (default: ./units)")
    units.add_argument("--root", default="/", metavar="PREFIX", help="the units run PREFIX/opt/statehub/...")
    units.add_argument("--systemd-version", type=int, metavar="N",
                       help="the targets' systemd (default: this machine's, else 252 as on Raspberry Pi OS "
                            "bookworm); 254+ gets a growing restart delay")
    units.set_defaults(func=cmd_units)

    deploy = sub.add_parser(
        "deploy", help="install a hub on its ECU over SSH and (re)start its systemd unit",
        description="Build the statehub wheel, install it into a new versioned venv on the hub's host "
                    "(/opt/statehub/releases/VERSION-HASH), install hubs.toml and the hub's systemd unit, switch "
                    "the hub's `current` link to it, restart the unit and wait for the hub on Zenoh. A failure "
                    "leaves the previous release running. Deploying the same code and hubs.toml again reuses "
                    "the release.")
    _target_options(deploy)
    deploy.add_argument("--trust-new-host", action="store_true",
                        help="first contact: record the host key in the station's known_hosts (check its fingerprint)")
    deploy.add_argument("--offline-deps", action="store_true",
                        help="install the wheel without its dependencies (pip --no-deps --no-index) into a venv "
                             "made with --system-site-packages, so that they come from the target's python; "
                             "for targets without PyPI access whose python already has them (and for tests)")
    deploy.add_argument("--wheel", metavar="FILE", help="deploy this wheel instead of building one")
    deploy.add_argument("--source", metavar="DIR", help="the statehub checkout to build (default: this one)")
    deploy.add_argument("--python", default="python3", help="the target's interpreter for the venv (python3)")
    deploy.set_defaults(func=cmd_deploy)

    rollback = sub.add_parser("rollback", help="run the hub's previous release again",
                              description="Switch the hub's `current` back to the release deployed before the "
                                          "current one (from releases.log on the target) and restart its unit.")
    _target_options(rollback)
    rollback.add_argument("--to", metavar="RELEASE", help="switch to this release instead (a directory name under "
                                                          "/opt/statehub/releases)")
    rollback.set_defaults(func=cmd_rollback)
