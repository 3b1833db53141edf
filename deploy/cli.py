"""hubctl: the single entry point of statehub."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence

from common.model import ModelError, ParseError, parse_predicate

from .models import DEFAULT_MODEL, ModelLoadError, load_model


def _fail(message: str, code: int = 2) -> int:
    print(f"hubctl: {message}", file=sys.stderr)
    return code


def cmd_check(args: argparse.Namespace) -> int:
    from common.model.compiled import CompiledModel
    from controller.planner import Planner, check_operations
    from controller.synthesis import synthesize

    model = load_model(args.model)
    print(f"model {model.name}: {len(model.resources)} resources, {len(model.variables)} variables, "
          f"{len(model.transitions)} transitions, {len(model.operations)} operations, "
          f"{len(model.specifications)} specifications: valid")
    supervisor = synthesize(model)
    print(f"supervisor: {len(supervisor.guards)} deliberate transitions get synthesized guards")
    for name, converged in supervisor.converged.items():
        if not converged:
            print(f"  warning: bad states of {name!r} did not converge within the round limit")
    compiled = CompiledModel(model, supervisor.guards)
    planner = Planner(compiled, supervisor.forbidden)
    began = time.perf_counter()
    problems = check_operations(model, compiled, planner)
    for problem in problems:
        print(f"  unreachable: {problem}")
    print(f"checked {len(model.operations)} operations in {time.perf_counter() - began:.2f} s: "
          f"{len(problems)} unreachable")
    return 1 if problems else 0


def cmd_plan(args: argparse.Namespace) -> int:
    from common.model.compiled import CompiledModel
    from controller.planner import NoPlan, Planner
    from controller.synthesis import synthesize

    from .statefile import load_state

    model = load_model(args.model)
    supervisor = synthesize(model)
    compiled = CompiledModel(model, supervisor.guards)
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
    planner = Planner(compiled, supervisor.forbidden)
    result = planner.plan(compiled.pack(start), goals, time_limit=args.time_limit)
    if isinstance(result, NoPlan):
        print(f"no plan: {result.reason}")
        if result.unreachable:
            print(f"  cannot be reached together: {', '.join(result.unreachable)}")
        return 1
    print(result.explain(compiled))
    stats = result.stats
    print(f"{len(result.steps)} steps, found in {stats.seconds * 1000:.1f} ms ({stats.method}, "
          f"{stats.expanded} states expanded)")
    return 0


def cmd_up(args: argparse.Namespace) -> int:
    from .local import run_in_process

    model = load_model(args.model)
    failure = {"nr": args.fail_rate} if args.fail_rate else None
    print(f"statehub: running station {model.name} in one process, emulated devices "
          f"(speed x{args.speed}, seed {args.seed})", flush=True)
    summary = run_in_process(model, speed=args.speed, seed=args.seed, failure=failure, realtime=args.realtime,
                             report=lambda line: print(line, flush=True))
    print()
    print(f"{'finished' if summary.finished else 'NOT finished'}: {summary.operations_finished}/"
          f"{summary.operations_total} operations, {summary.abilities} abilities started, {summary.plans} plans, "
          f"{summary.replans} replans, {summary.no_plans} goals without plan")
    print(f"station time {summary.emulated_seconds:.1f} s (emulated), wall {summary.wall_seconds:.1f} s, "
          f"planning {summary.planning_seconds:.2f} s")
    if not summary.finished:
        print(f"reason: {summary.reason}")
    return 0 if summary.finished else 1


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hubctl", description="statehub: state-based control of assembly stations")
    sub = parser.add_subparsers(dest="command", required=True)

    def with_model(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
        p.add_argument("--model", default=DEFAULT_MODEL, help=f"station model as module:function ({DEFAULT_MODEL})")
        return p

    up = with_model(sub.add_parser("up", help="run the whole station on this machine, emulated, to completion"))
    up.add_argument("--speed", type=float, default=1.0, help="scale every emulated delay (2 = twice as fast)")
    up.add_argument("--seed", type=int, default=0, help="seed of emulated outcomes")
    up.add_argument("--fail-rate", type=float, default=0.0, help="probability that the nutrunner fails a bolt")
    up.add_argument("--realtime", action="store_true", help="wait through emulated delays instead of skipping")
    up.set_defaults(func=cmd_up)

    plan = with_model(sub.add_parser("plan", help="print the shortest plan to a goal"))
    plan.add_argument("goal", nargs="+", help="an operation name or a predicate, e.g. 'engine.bolt7_e == tightened'")
    plan.add_argument("--from", dest="start", help="TOML file of variable values to start from")
    plan.add_argument("--time-limit", type=float, default=30.0)
    plan.set_defaults(func=cmd_plan)

    check = with_model(sub.add_parser("check", help="validate the model and every operation's reachability"))
    check.set_defaults(func=cmd_check)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ModelError, ModelLoadError) as exc:
        return _fail(str(exc))
    except KeyboardInterrupt:
        return _fail("interrupted", 130)
    except Exception as exc:
        from controller.synthesis import SynthesisError

        from .statefile import StateFileError

        if isinstance(exc, SynthesisError | StateFileError):
            return _fail(str(exc))
        raise


if __name__ == "__main__":
    sys.exit(main())
