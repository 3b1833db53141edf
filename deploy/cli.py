"""hubctl: the single entry point of statehub."""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from common.config.hubs_toml import ConfigError, ConfigProblem, StationConfig, load_config, load_station
from common.config.modes import DEFAULT_EXECUTION, DeviceMode, Execution, argument
from common.config.production import ProductionConfig, ProductionError, plan_from_options
from common.model import DurationTable, Model, ParseError, TransitionKind, parse_predicate
from common.model.durations import DurationSource, effect_owner
from common.plumbing.lifecycle import EXPECTED_ERRORS, exit_process, one_line, positive
from common.stations import DEFAULT_MODEL, load_model
from controller import main as controller_process
from hubs import main as hub_process
from hubs.main import parse_failures

from .orders_cli import add_production_options, production_plan, register_orders_command

if TYPE_CHECKING:
    from common.model import Predicate
    from controller.planner import Plan, Planner


def _fail(message: str, code: int = 2) -> int:
    print(f"hubctl: {message}", file=sys.stderr)
    return code


def _model_and_durations(args: argparse.Namespace) -> tuple[Model, DurationTable, StationConfig | None]:
    """`--config`: the station's model, its devices' `delay` and the station; else `--model` at its declared
    durations (and no station)."""
    from common.resources import durations_of

    if args.config is None:
        model = load_model(args.model)
        return model, durations_of(model), None
    if args.model != DEFAULT_MODEL:
        raise ConfigError([ConfigProblem(args.config, None, "", "give --model or --config, not both")])
    config, model = load_station(args.config)
    return model, durations_of(model, config.delays), config


def _duration_lines(durations: DurationTable, resources: Iterable[str] | None = None) -> list[str]:
    """One line per resource: its device type, its effects' duration and where that was declared."""
    wanted = None if resources is None else set(resources)
    entries = [e for e in durations.entries if wanted is None or e.resource in wanted]
    width = max((len(e.resource) for e in entries), default=0)
    type_width = max((len(e.device_type) for e in entries), default=0)
    own = [(name, d) for name, d in durations.own_effects.items()
           if wanted is None or name.split(".", 1)[0] in wanted]
    return [f"  {e.resource:<{width}}  {e.device_type or '-':<{type_width}}  {e.duration!s:<10}  {e.source.value}"
            for e in entries] + [f"    {name}  {d!s:<10}  its ability's own, whatever the device's" for name, d in own]


def cmd_check(args: argparse.Namespace) -> int:
    from controller.planner import check_operations
    from controller.stack import build_controller_stack
    from controller.timing_hazards import timing_hazards

    model, durations, _ = _model_and_durations(args)
    print(f"model {model.name}: {len(model.resources)} resources, {len(model.variables)} variables, "
          f"{len(model.transitions)} transitions, {len(model.operations)} operations, "
          f"{len(model.specifications)} specifications: valid")
    print("durations of the effects, per resource (type, seconds, declared by):")
    print("\n".join(_duration_lines(durations)))
    for entry in durations.entries:
        if entry.source is DurationSource.FALLBACK:
            print(f"  warning: {entry.resource}'s type {entry.device_type or '(none)'!r} declares no duration: "
                  f"its effects run on the fallback guess {entry.duration}")
    stack = build_controller_stack(model)
    supervisor = stack.supervisor
    print(f"supervisor: {len(supervisor.guards)} deliberate transitions get synthesized guards")
    for name, converged in supervisor.converged.items():
        if not converged:
            print(f"  warning: bad states of {name!r} did not converge within the round limit")
    hazards = timing_hazards(model, durations, supervisor.guards)
    print(f"timing hazards: {len(hazards)} (warnings: a plan may count on an effect the station does not wait for)")
    for hazard in hazards:
        print(f"  warning [{hazard.kind.value}]: {hazard}")
    began = time.perf_counter()
    problems = check_operations(model, stack.compiled, stack.planner)
    for problem in problems:
        print(f"  unreachable: {problem}")
    print(f"checked {len(model.operations)} operations in {time.perf_counter() - began:.2f} s: "
          f"{len(problems)} unreachable")
    return 1 if problems else 0


def cmd_plan(args: argparse.Namespace) -> int:
    from controller.makespan import earliest_schedule, makespan
    from controller.planner import Budget, NoPlan
    from controller.stack import build_controller_stack

    from .local.statefile import load_state

    model, durations, config = _model_and_durations(args)
    execution = config.controller.execution if config is not None else DEFAULT_EXECUTION
    stack = build_controller_stack(model)
    compiled = stack.compiled
    goals = {}
    for text in args.goal:
        if text in model.operation_by_name:
            goals[text] = model.operation_by_name[text].goal
            continue
        try:
            goal = parse_predicate(text)
        except ParseError as exc:
            return _fail(f"goal is neither an operation of {model.name} nor a predicate: {exc}")
        problems = model._check_predicate("goal", goal, model.variables)
        if problems:
            return _fail("\n".join(str(p) for p in problems))
        goals[text] = goal
    start = model.initial_state()
    if args.start:
        start.update(load_state(args.start, model))
    budget = Budget(first_expansions=10_000_000, improve_expansions=10_000_000, seconds=args.time_limit,
                    improve_seconds=args.time_limit)
    result = stack.planner.plan(compiled.pack(start), goals, budget=budget)
    if isinstance(result, NoPlan):
        print(f"no plan: {result.reason}")
        if result.unreachable:
            print(f"  cannot be reached together: {', '.join(result.unreachable)}")
        return 1
    print(result.explain(compiled, synthesized=args.guards))
    stats = result.stats
    first = (f"; first plan ({stats.first_length} steps) in {stats.first_seconds * 1000:.1f} ms"
             if stats.first_length >= 0 else "")
    shortest = "a shortest plan" if stats.minimal else "not shown to be a shortest plan within the budget"
    print(f"{len(result.steps)} steps, {shortest}: found in {stats.seconds * 1000:.1f} ms ({stats.method}, "
          f"{stats.expanded} states expanded{first})")
    steps = [model.transition_by_name[step.transition] for step in result.steps]
    effects = [t for t in steps if t.kind is TransitionKind.EFFECT]
    print("durations planned with (per resource: type, seconds, declared by):")
    print("\n".join(_duration_lines(durations, {effect_owner(t) for t in effects})) or "  (no effect in the plan)")
    one_by_one = sum(durations.of_transition(t).max_s for t in effects)
    print(f"predicted makespan: {makespan(earliest_schedule(steps, durations)):.2f} s with each step as early as its "
          f"causal order allows and each effect at its longest ({one_by_one:.2f} s one step after another)")
    from controller.retime import longest_seconds

    _print_faster_order(stack.planner, result, goals, longest_seconds(compiled, durations.keyed()), execution)
    return 0


def _print_faster_order(planner: Planner, plan: Plan, goals: Mapping[str, Predicate], seconds: Mapping[str, float],
                        execution: Execution) -> None:
    """The order the controller sends the plan out in when the portfolio's member that improves plans by time
    (controller/retime.py) finds a faster one in the engine's order (`execution`, hubs.toml's)."""
    from controller.planner.policy import RETIME_LIVE_TRIES
    from controller.retime import retime
    from controller.timed_check import Revalidation

    found = retime(planner.compiled, plan, seconds, execution, Revalidation(planner, goals, frozenset()),
                   tries=RETIME_LIVE_TRIES)
    if found is None:
        print(f"no faster order of these steps in the engine's {execution} order (controller/retime.py)")
        return
    print(f"the controller takes these steps in a faster order, predicted to end at {found.after_s:.2f} s instead of "
          f"{found.before_s:.2f} s in the engine's {execution} order, each effect at its longest "
          f"(controller/retime.py, {found.tried} orders checked):")
    print(found.plan.explain(planner.compiled))


DEFAULT_CONFIG = "hubs.toml"


def _in_process_station(args: argparse.Namespace) -> tuple[Model, StationConfig | None]:
    """The model `up --in-process` runs, and the hubs.toml it comes with (None: a model without one):
    `--model` if given (with `--config` if given too: its devices' delays), else the one `--config` names.

    Without either, ./hubs.toml's model, or the reference station where there is no
    hubs.toml (run from outside a station's directory)."""
    path = Path(args.config or DEFAULT_CONFIG)
    if args.config is not None and not path.is_file():
        raise ConfigError([ConfigProblem(str(path), None, "", "no such file (--config)")])
    if args.model is not None:
        return load_model(args.model), load_config(path) if args.config is not None else None
    if not path.is_file():
        return load_model(DEFAULT_MODEL), None
    config, model = load_station(path)
    return model, config


def cmd_up(args: argparse.Namespace) -> int:
    failure = parse_failures(args.failure)
    if args.fail_rate:
        failure.setdefault("nr", args.fail_rate)
    if args.chaos < 0:
        return _fail(f"--chaos {args.chaos}: the number of kills cannot be negative")
    if args.chaos and args.in_process:
        return _fail("--chaos kills processes: it needs the station as processes, not --in-process")
    if args.real and args.in_process:
        return _fail("--real runs a device's driver: it needs the station as processes, not --in-process")
    if not args.in_process:
        from .local.station import Options, up

        config = args.config or DEFAULT_CONFIG
        if not Path(config).is_file():
            return _fail(f"{config}: no such file (--config)")
        from hubs.factory import check_devices, check_real

        station = load_config(config)
        try:
            check_real(station, args.real)
        except ValueError as exc:
            return _fail(str(exc))
        # A device without driver, or a bad parameter, stops here (the sim world adds simulator addresses).
        check_devices(station, mode=args.mode, world=args.mode == DeviceMode.SIM, real=args.real)
        production = production_plan(args, station, station.load_model())
        if production is not None:
            # Checked here, so that a bad option stops before any process starts; the station's loop
            # queues them once it runs orders (ProductionPlan, common/config/production.py).
            print(f"statehub: production: {production.describe()}", flush=True)
        if args.model is not None:
            # Every process loads the model its hubs.toml names: one given here could not reach them.
            named = station.station.model
            if args.model != named:
                return _fail(f"--model {args.model}: `up` runs the model {config} names ({named}); give the model "
                             f"in that file's [station] model, or use --in-process")
        return up(Options(config=config, speed=args.speed, seed=args.seed, mode=args.mode, real=frozenset(args.real),
                          failure=failure,
                          time_limit=args.time_limit, resume=args.resume, hold=args.hold, record=not args.no_record,
                          chaos=args.chaos, orders=args.orders, mix=args.mix, production=production,
                          execution=args.execution))
    from controller.planner.policy import VIRTUAL_BUDGET

    from .local.inprocess import emulated_delays, run_in_process

    model, in_process_config = _in_process_station(args)
    in_process_plan = None
    if args.orders is not None or args.mix is not None:
        in_process_plan = plan_from_options(args.orders, args.mix, ProductionConfig(), model, "--orders")
        if in_process_plan is not None:
            print(f"statehub: production: {in_process_plan.describe()}", flush=True)
    execution = args.execution or (in_process_config.controller.execution if in_process_config is not None
                                   else DEFAULT_EXECUTION)
    print(f"statehub: running station {model.name} in one process, emulated devices "
          f"(speed x{args.speed}, seed {args.seed}, plans in {execution})", flush=True)
    budget = replace(VIRTUAL_BUDGET, first_expansions=args.plan_expansions, improve_expansions=args.improve_expansions)
    recording = None
    if not args.no_record:
        from .local.recordings import in_process_recording

        config = args.config or (DEFAULT_CONFIG if args.model is None and Path(DEFAULT_CONFIG).is_file() else None)
        reference = args.model or (load_config(config).station.model if config else DEFAULT_MODEL)
        recording = in_process_recording(model, reference, config, seed=args.seed, budget=budget)
    summary = run_in_process(model, speed=args.speed, seed=args.seed, failure=failure or None,
                             delays=emulated_delays(in_process_config) if in_process_config is not None else None,
                             realtime=args.realtime, time_limit=args.time_limit,
                             report=lambda line: print(line, flush=True), budget=budget, recording=recording,
                             production=in_process_plan, execution=execution)
    print()
    orders_done = summary.throughput.orders if summary.throughput is not None else 0
    done = (f"{orders_done}/{len(in_process_plan.orders)} orders" if in_process_plan is not None else
            f"{summary.operations_finished}/{summary.operations_total} operations")
    print(f"{'finished' if summary.finished else 'NOT finished'}: {done}, {summary.abilities} abilities started, "
          f"{summary.plans} plans, {summary.replans} replans, {summary.no_plans} goals without plan")
    print(f"station time {summary.emulated_seconds:.1f} s (emulated), wall {summary.wall_seconds:.1f} s, "
          f"planning {summary.planning_seconds:.2f} s")
    if not summary.finished:
        print(f"reason: {summary.reason}")
    if recording is not None:
        print(f"recording: {recording.path} (hubctl replay {recording.path})")
        from .runs.cli import timeline_after_run

        timeline_after_run(recording.path)
    return 0 if summary.finished else 1


def cmd_console(args: argparse.Namespace) -> int:
    from controller.console.app import run_console

    listen = [] if args.listen == "none" else [args.listen]
    return run_console(args.config, connect=args.connect, listen=listen, operator=args.operator, certs=args.certs)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hubctl", description="statehub: state-based control of assembly stations")
    sub = parser.add_subparsers(dest="command", required=True)

    def with_model(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
        p.add_argument("--model", default=DEFAULT_MODEL,
                       help=f"station model: module:function or file.py:function ({DEFAULT_MODEL})")
        return p

    def with_config(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
        p.add_argument("--config", default="hubs.toml", help="the station's hubs.toml (default: ./hubs.toml)")
        return p

    up = sub.add_parser(
        "up", help="run the whole station on this machine (controller and every hub as processes) to completion")
    # No defaults here: whether --config or --model was given decides which model runs (_in_process_station).
    up.add_argument("--model", help="station model as module:function (default: the one --config names; "
                                    "with --in-process it wins over --config)")
    up.add_argument("--config", help=f"the station's hubs.toml (default: ./{DEFAULT_CONFIG})")
    up.add_argument("--speed", type=positive, default=1.0, help="scale every emulated delay (2 = twice as fast)")
    up.add_argument("--seed", type=int, default=0, help="seed of emulated outcomes (and of --chaos)")
    up.add_argument("--mode", type=argument(DeviceMode), choices=list(DeviceMode),
                    help="run every device in this mode (default: as in hubs.toml)")
    up.add_argument("--real", action="append", default=[], metavar="RESOURCE",
                    help="run this device in mode real whatever hubs.toml or --mode says, e.g. --real human: the "
                         "operator's page, whose address up prints (repeatable)")
    up.add_argument("--failure", action="append", default=[], metavar="RESOURCE=P",
                    help="probability of an emulated device's alternative outcome, e.g. nr=0.1 (repeatable)")
    up.add_argument("--fail-rate", type=float, default=0.0, help="shorthand for --failure nr=P")
    up.add_argument("--time-limit", type=positive, default=900.0,
                    help="give up after this many seconds (with --in-process: of emulated time)")
    up.add_argument("--resume", action="store_true", help="keep the controller's persisted state of the last run")
    up.add_argument("--hold", action="store_true",
                    help="start no operation: the operator starts them from `hubctl console`")
    up.add_argument("--no-record", action="store_true",
                    help="do not record the run (default: into [controller.recording] dir, see `hubctl replay`)")
    up.add_argument("--chaos", type=int, default=0, metavar="N",
                    help="kill -9 N random hubs or the controller at random moments of the run (from --seed); "
                         "each is restarted as its systemd unit would be")
    up.add_argument("--execution", type=argument(Execution), choices=list(Execution),
                    help="how a plan's steps wait for each other: the trace, the partial order (the operator works "
                         "while the robot does), or one step after another (default: [controller] execution of "
                         "hubs.toml, trace)")
    up.add_argument("--in-process", action="store_true",
                    help="run controller and emulated devices in this one process, in virtual time (no Zenoh)")
    up.add_argument("--realtime", action="store_true", help="with --in-process: wait through emulated delays")
    up.add_argument("--plan-expansions", type=int, default=20_000, metavar="N",
                    help="with --in-process: states the first-plan search may expand per request (default 20000)")
    up.add_argument("--improve-expansions", type=int, default=0, metavar="N",
                    help="with --in-process: states A* may expand looking for a shorter plan than the first "
                         "(default 0: keep the first plan, the quickest run)")
    add_production_options(up)
    up.set_defaults(func=cmd_up)

    hub = sub.add_parser("hub", help="run one hub of hubs.toml (what its systemd unit runs: python -m hubs)")
    hub_process.add_arguments(hub)
    hub.set_defaults(func=hub_process.serve)

    ctl = sub.add_parser("controller", help="run the controller (what its systemd unit runs: python -m controller)")
    controller_process.add_arguments(ctl)
    ctl.set_defaults(func=controller_process.serve)

    selftest = sub.add_parser("selftest", help="run a hub's self-test; exit 1 on a failure")
    hub_process.add_selftest_arguments(selftest)
    selftest.set_defaults(func=hub_process.selftest)

    console = with_config(sub.add_parser(
        "console", help="the operator console: watch and steer the running station (a terminal UI over Zenoh)"))
    console.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                         help="the controller's zenoh endpoint, e.g. tcp/decs.local:7447 (default: its listeners "
                              "in hubs.toml, on this host)")
    console.add_argument("--listen", default="tcp/0.0.0.0:0", metavar="ENDPOINT",
                         help="where the hubs may link to the console for their self-test reports (peers do not "
                              "route; default: any interface, a free port; `none`: do not listen)")
    console.add_argument("--as", dest="operator", metavar="OPERATOR",
                         help="with [security] mode = \"tls\": the operator whose certificate to present "
                              "(default: the first of [security] operators)")
    console.add_argument("--certs", metavar="DIR", help="the certificate directory (default: [security] certs)")
    console.set_defaults(func=cmd_console)

    from controller.overview import main as overview_process

    overview = sub.add_parser("overview", help="the supervisors' read-only station overview: a web page (operations, "
                                                "plan, health, orders, the run's Gantt chart)")
    overview_process.add_arguments(overview)
    overview.set_defaults(func=overview_process.serve)

    def with_station(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
        with_model(p).add_argument(
            "--config", help="take the model and the devices' `delay` (durations) from this hubs.toml instead")
        return p

    plan = with_station(sub.add_parser("plan", help="print the shortest plan to a goal, its durations and makespan"))
    plan.add_argument("goal", nargs="+", help="an operation name or a predicate, e.g. 'engine.bolt7_e == tightened'")
    plan.add_argument("--from", dest="start", help="TOML file of variable values to start from")
    plan.add_argument("--time-limit", type=float, default=30.0,
                      help="seconds for the first plan, and again for a shorter one (default 30)")
    plan.add_argument("--guards", action="store_true",
                      help="print each step's synthesized guard in full instead of naming its specifications")
    plan.set_defaults(func=cmd_plan)

    check = with_station(sub.add_parser(
        "check", help="validate the model, print its durations, name its timing hazards and check every operation's "
                      "reachability"))
    check.set_defaults(func=cmd_check)

    from .remote.cli import register_deploy_commands

    register_deploy_commands(sub)

    from .certs import register_certs_commands

    register_certs_commands(sub)

    from .modeltest.cli import register_test_command

    register_test_command(sub)

    from .scaffold.cli import register_scaffold_commands

    register_scaffold_commands(sub)

    from .replay.cli import register_replay_command

    register_replay_command(sub)

    from .runs.cli import register_run_commands

    register_run_commands(sub)
    register_orders_command(sub)
    from .router.cli import register_router_command

    register_router_command(sub)
    from .line.cli import register_line_commands

    register_line_commands(sub)

    from .export_cli import register_export_command

    register_export_command(sub, DEFAULT_MODEL)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except EXPECTED_ERRORS as exc:
        return _fail(one_line(exc))
    except KeyboardInterrupt:
        return _fail("interrupted", 130)
    except BrokenPipeError:
        # The reader went away (`hubctl timeline RUN | head`): nothing more to say, and the interpreter
        # must not fail again flushing stdout at exit.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except Exception as exc:
        from controller.synthesis import SynthesisError

        from .local.statefile import StateFileError

        if isinstance(exc, SynthesisError | StateFileError | ProductionError):
            return _fail(str(exc))
        raise


def run() -> None:
    """The `hubctl` console script: `main`, then leave as every zenoh process must (`exit_process`)."""
    exit_process(main())


if __name__ == "__main__":
    run()
