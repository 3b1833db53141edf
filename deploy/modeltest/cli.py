"""`hubctl test HUB`: the generated model-based tests against a running hub (DESIGN.md §8, §9).

The command acts as the station's controller (it listens where the controller would, or
on loopback with `--loopback-port`), so the controller itself must not run: it refuses
when another controller commands the hub's resources. Resources that move
(`unsafe_for_random_commands`, the robot) are refused unless `--allow-motion`, which is
itself refused unless every device of the hub is simulated or emulated.

`--simulated-operator [DEVICE]` tests an operator's page (the operator's device in mode real): a
simulated operator presses its Confirm through the page's endpoint, with DEVICE's token, whenever the
page allows it (simulated_operator.py); without it the test waits for a person to press.

Exit status: 0 every resource passed, 1 a test failed, 2 refused or could not run.

This module is imported by hubctl at start-up: the test machinery (Hypothesis, Zenoh)
is imported only when `hubctl test` runs.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from common.config.hubs_toml import ConfigError, StationConfig, load_config, load_station
from common.config.modes import DeviceMode, NetworkMode
from common.model import Model, ModelError
from common.plumbing.lifecycle import exit_process
from common.stations import ModelLoadError, load_model

if TYPE_CHECKING:
    from .link import BusThread
    from .runner import Target
    from .session import Options
    from .simulated_operator import SimulatedOperator

HUB_WAIT_S = 10.0
CONTROLLER_WATCH_S = 1.0


class Refused(Exception):
    """The test must not (or cannot) run; the message says why and what to do."""


@dataclass
class Selection:
    resources: list[str]
    notes: list[str] = field(default_factory=list)


def select_resources(config: StationConfig, model: Model, hub: str, wanted: list[str] | None,
                     allow_motion: bool) -> Selection:
    """The resources of `hub` to test, after the safety rules; raises Refused."""
    if hub not in config.hubs:
        raise Refused(f"{config.path}: no hub named {hub!r} (hubs: {', '.join(config.hubs)})")
    devices = config.hubs[hub].devices
    for name in wanted or ():
        if name not in devices:
            owner = config.resources.get(name)
            where = f"it is served by hub {owner.name!r}" if owner else "no hub serves it"
            raise Refused(f"resource {name!r} is not served by hub {hub!r} ({where}; {hub} serves: "
                          f"{', '.join(devices) or 'nothing'})")
        if name not in model.resource_by_name:
            raise Refused(f"resource {name!r} is not in model {model.name!r}")
    if allow_motion:
        real = [d for d in devices.values() if d.mode == DeviceMode.REAL]
        if real:
            listed = ", ".join(f"{d.resource} ({config.path}:{d.line})" if d.line else d.resource for d in real)
            raise Refused(f"--allow-motion refused: hub {hub} has devices in 'real' mode: {listed}. Random commands "
                          f"could move real hardware; --allow-motion is for hubs whose devices are all 'sim' or "
                          f"'emulate' in {config.path}")
    chosen = list(wanted) if wanted else list(devices)
    selection = Selection([])
    unsafe = [r for r in chosen if model.resource_by_name[r].unsafe_for_random_commands]
    if unsafe and not allow_motion:
        others = [r for r in chosen if r not in unsafe]
        hint = f"; to test only the others: {' '.join(f'--resource {r}' for r in others)}" if others else ""
        raise Refused(f"{', '.join(unsafe)} {'is' if len(unsafe) == 1 else 'are'} marked unsafe_for_random_commands "
                      f"(random commands make it move): pass --allow-motion to test it on a simulated or emulated "
                      f"device{hint}")
    for name in chosen:
        if not model.resource_by_name[name].commands:
            selection.notes.append(f"{name}: skipped, it has no command variables (nothing to command)")
        else:
            selection.resources.append(name)
    if not selection.resources:
        raise Refused(f"hub {hub} serves no resource with command variables to test ({', '.join(chosen)})")
    return selection


def open_bus(target: Target) -> tuple[BusThread, str]:
    """Listen where the controller would; if that address is taken, connect to it instead."""
    from common.bus.zenoh_config import zenoh_config

    from .link import BusThread, LinkError

    listen = f"listening on {', '.join(target.listen)}" if target.listen else ""
    connect = f"connecting to {', '.join(target.connect)}" if target.connect else ""
    where = "; ".join(w for w in (listen, connect) if w) or "with no endpoints"
    try:
        config = zenoh_config(target.mode, target.listen, target.connect, target.lease_ms, tls=target.tls)
        return BusThread(config, description=where).start(), where
    except LinkError as first:
        if not target.listen or target.mode != NetworkMode.PEER:
            raise
        endpoints = [e.replace("0.0.0.0", "127.0.0.1") for e in target.listen]
        fallback = f"connecting to {', '.join(endpoints)} (cannot listen there: {first})"
        config = zenoh_config(NetworkMode.PEER, (), endpoints, target.lease_ms, tls=target.tls)
        return BusThread(config, description=fallback).start(), fallback


def wait_for_hub(bus: BusThread, station: str, hub: str, timeout: float) -> None:
    from .link import alive_hubs

    deadline = time.monotonic() + timeout
    while True:
        alive = alive_hubs(bus, station, timeout=0.5)
        if hub in alive:
            return
        if time.monotonic() >= deadline:
            others = f" (alive: {', '.join(sorted(alive))})" if alive else ""
            raise Refused(f"hub {hub} is not running or not connected: no liveliness token on "
                          f"{station}/hub/{hub}/alive within {timeout:g} s{others}. Start it (hubctl hub {hub}); "
                          f"on one machine give both the same --loopback-port")
        time.sleep(0.3)


def cmd_test(args: argparse.Namespace) -> int:
    try:
        from .link import LinkError, watch_controllers
        from .runner import Target
        from .session import Options
    except ImportError as exc:  # Hypothesis is a test dependency
        print(f"hubctl test needs the test dependencies ({exc}): pip install 'statehub[test]'", file=sys.stderr)
        return 2
    if args.model:  # the station's own model need not even import
        config, model = load_config(args.config), load_model(args.model)
    else:
        config, model = load_station(args.config)
    try:
        selection = select_resources(config, model, args.hub, args.resource, args.allow_motion)
    except Refused as exc:
        print(f"hubctl test: refused: {exc}")
        return 2
    target = Target.of(config, model, loopback_port=args.loopback_port, certs=args.certs)
    options = Options(examples=args.examples, max_steps=args.max_steps, deadline=args.deadline, seed=args.seed)
    print(f"hubctl test {args.hub}: {', '.join(selection.resources)} against model {model.name}; "
          f"{options.examples} examples of up to {options.max_steps} commands, deadline {options.deadline:g} s",
          flush=True)
    for note in selection.notes:
        print(f"  {note}")
    try:
        bus, where = open_bus(target)
    except LinkError as exc:
        print(f"hubctl test: cannot join the station's network: {exc}")
        return 2
    try:
        print(f"  acting as the controller, {where}", flush=True)
        seconds = max(CONTROLLER_WATCH_S, 3.0 / config.controller.command_rate_hz)
        others = watch_controllers(bus, config.station.name, model, selection.resources, seconds)
        if others:
            seen = "; ".join(f"{c} commanding {', '.join(sorted(rs))}" if rs else c for c, rs in others.items())
            print(f"hubctl test: refused: a controller is running on station {config.station.name}: {seen}. "
                  f"Stop it first: two controllers would fight over the hub")
            return 2
        wait_for_hub(bus, config.station.name, args.hub, HUB_WAIT_S)
        operators = simulated_operators(config, model, selection.resources, args.simulated_operator, args.certs)
        try:
            return _run(bus, target, selection.resources, options)
        finally:
            for operator in operators:
                operator.stop()
                print(operator.describe(), flush=True)
    except Refused as exc:
        print(f"hubctl test: refused: {exc}")
        return 2
    finally:
        bus.close()


def simulated_operators(config: StationConfig, model: Model, resources: list[str], device: str | None,
                        certs: str | None) -> list[SimulatedOperator]:
    """With `--simulated-operator`: one pressing on each operator's page under test, started once its page
    answers; raises Refused when a page cannot be pressed on."""
    if device is None:
        return []
    from .simulated_operator import NoOperatorPage, SimulatedOperator, page_access

    operators = [r for r in resources if model.resource_by_name[r].device_type == "operator"]
    if not operators:
        raise Refused(f"--simulated-operator: no operator among the resources under test ({', '.join(resources)})")
    started: list[SimulatedOperator] = []
    try:
        for resource in operators:
            operator = SimulatedOperator(page_access(config, resource, device or None, certs))
            operator.wait_for_page(HUB_WAIT_S)
            started.append(operator.start())
            print(f"  a simulated operator presses Confirm on {operator.access.url} whenever it may", flush=True)
    except NoOperatorPage as exc:
        for operator in started:
            operator.stop()
        raise Refused(str(exc)) from None
    return started


def _run(bus: BusThread, target: Target, resources: list[str], options: Options) -> int:
    from .link import LinkError
    from .runner import run_model_test

    code = 0
    summary = []
    for resource in resources:
        print(f"{resource}:", flush=True)
        try:
            report = run_model_test(target, resource, options, bus=bus, listen_for_controllers=0.0,
                                    say=lambda line: print(line, flush=True))
        except LinkError as exc:
            print(f"hubctl test: refused: {exc}")
            return 2
        print(report.describe(), flush=True)
        if report.aborted is not None:
            code = max(code, 2)
            summary.append(f"{resource}: not run to the end")
        elif report.passed:
            summary.append(f"{resource}: passed")
        else:
            code = max(code, 1)
            summary.append(f"{resource}: FAILED")
    print("; ".join(summary))
    return code


def register_test_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    """Add `hubctl test` to hubctl's subcommands (deploy/cli.py build_parser)."""

    def positive(text: str) -> float:
        value = float(text)
        if value <= 0:
            raise argparse.ArgumentTypeError(f"must be positive, got {text}")
        return value

    def count(text: str) -> int:
        value = int(text)
        if value < 1:
            raise argparse.ArgumentTypeError(f"must be 1 or more, got {text}")
        return value

    parser = sub.add_parser(
        "test", help="model-based test of a running hub: random command sequences over Zenoh, checked against "
                     "the model (exit 1 on a failure; the controller must not run)")
    parser.add_argument("hub", help="the hub to test, e.g. pi-tool")
    parser.add_argument("--config", default="hubs.toml", help="the station's hubs.toml (default: ./hubs.toml)")
    parser.add_argument("--resource", action="append", metavar="R",
                        help="test only this resource of the hub (repeatable; default: all it serves)")
    parser.add_argument("--examples", type=count, default=20, help="command sequences to try (default 20)")
    parser.add_argument("--max-steps", type=count, default=6, help="commands per sequence (default 6)")
    parser.add_argument("--deadline", type=positive, default=2.0,
                        help="seconds for the hub to mirror a command and for each expected effect (default 2)")
    parser.add_argument("--allow-motion", action="store_true",
                        help="also test resources that move (the robot); only if every device of the hub is "
                             "in sim or emulate mode")
    parser.add_argument("--loopback-port", type=int,
                        help="run on loopback: listen on 127.0.0.1:PORT, where the hub (started with the same "
                             "--loopback-port) connects")
    parser.add_argument("--seed", type=int, help="Hypothesis seed, to repeat a run")
    parser.add_argument("--certs", metavar="DIR",
                        help="with [security] mode = \"tls\": the certificate directory holding the controller's "
                             "certificate (default: [security] certs)")
    parser.add_argument("--model", help="hold the hub to this model (module:function) instead of the station's")
    parser.add_argument("--simulated-operator", nargs="?", const="", metavar="DEVICE",
                        help="an operator's page (device in mode real) under test: a simulated operator presses "
                             "Confirm through its endpoint whenever the page allows, with the token of DEVICE in "
                             "hubs.toml (default: the page's only token, or none)")
    parser.set_defaults(func=cmd_test)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """`python -m deploy.modeltest.cli test HUB ...`: the same as `hubctl test HUB ...`."""
    parser = argparse.ArgumentParser(prog="hubctl")
    register_test_command(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except (ConfigError, ModelError, ModelLoadError) as exc:
        print(f"hubctl: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("hubctl: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    exit_process(main())
