"""`hubctl export pddl`: a station's planning task as a PDDL domain and problem (docs/pddl.md)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from common.model import Model, ParseError, Predicate, all_of, parse_predicate


class GoalError(ValueError):
    pass


def goals_of(model: Model, texts: list[str], start: dict) -> dict[str, Predicate]:
    """Operation names or predicates; none given: every operation whose precondition holds at the start."""
    if not texts:
        return {op.name: op.goal for op in model.operations if op.pre.eval(start)}
    goals: dict[str, Predicate] = {}
    for text in texts:
        if text in model.operation_by_name:
            goals[text] = model.operation_by_name[text].goal
            continue
        try:
            goal = parse_predicate(text)
        except ParseError as exc:
            raise GoalError(f"goal {text!r} is neither an operation of {model.name} nor a predicate: {exc}") from None
        problems = model._check_predicate("goal", goal, model.variables)
        if problems:
            raise GoalError(f"goal {text!r}: " + "; ".join(str(p) for p in problems))
        goals[text] = goal
    return goals


def cmd_export_pddl(args: argparse.Namespace) -> int:
    from common.config.hubs_toml import load_station
    from common.stations import DEFAULT_MODEL, load_model
    from controller.pddl import Flavour, Unexpressible, encode, render, render_sas
    from controller.stack import build_controller_stack

    from .local.statefile import load_state

    if args.config is not None and args.model != DEFAULT_MODEL:
        print("hubctl: give --model or --config, not both", file=sys.stderr)
        return 2
    model = load_station(args.config)[1] if args.config else load_model(args.model)
    start = model.initial_state()
    if args.start:
        start.update(load_state(args.start, model))
    try:
        goals = goals_of(model, args.goal, start)
    except GoalError as exc:
        print(f"hubctl: {exc}", file=sys.stderr)
        return 2
    if not goals:
        print(f"hubctl: no goal given and no operation of {model.name} can start from this state", file=sys.stderr)
        return 2
    stack = build_controller_stack(model)
    compiled = stack.compiled
    try:
        task = encode(compiled, compiled.pack(start), all_of(*goals.values()), stack.supervisor.forbidden)
    except Unexpressible as exc:
        print(f"hubctl: {model.name} cannot be written in PDDL: {exc}", file=sys.stderr)
        return 1
    flavour = Flavour.INLINE if args.no_axioms else Flavour.AXIOMS
    domain, problem = render(task, flavour)
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        (out / "domain.pddl").write_text(domain)
        (out / "problem.pddl").write_text(problem)
        if args.sas:
            (out / "output.sas").write_text(render_sas(task))
    except OSError as exc:
        print(f"hubctl: --out {out}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    print(f"wrote {out / 'domain.pddl'} ({len(task.actions)} actions, {len(task.facts)} facts"
          f"{', derived predicates' if flavour is Flavour.AXIOMS else ', no derived predicates'}) and "
          f"{out / 'problem.pddl'} (goals: {', '.join(goals)})")
    if args.sas:
        print(f"wrote {out / 'output.sas'} (SAS+: the model's {len(compiled.paths)} variables multi-valued, for "
              f"Fast Downward's or SymK's search without the translator)")
    return 0


def register_export_command(sub: argparse._SubParsersAction, default_model: str) -> None:
    export = sub.add_parser("export", help="write the station in another tool's language")
    kinds = export.add_subparsers(dest="format", required=True)
    pddl = kinds.add_parser(
        "pddl", help="a PDDL domain and problem of the compiled model from a state to goals (docs/pddl.md)")
    pddl.add_argument("goal", nargs="*", help="operation names or predicates (default: every operation whose "
                                              "precondition holds at the start)")
    pddl.add_argument("--out", required=True, help="directory for domain.pddl and problem.pddl")
    pddl.add_argument("--from", dest="start", help="TOML file of variable values to start from")
    pddl.add_argument("--model", default=default_model,
                      help=f"station model: module:function or file.py:function ({default_model})")
    pddl.add_argument("--config", help="take the model from this hubs.toml instead")
    pddl.add_argument("--no-axioms", action="store_true",
                      help="write every condition in place instead of as derived predicates (for tools without "
                           ":derived-predicates; large on a station)")
    pddl.add_argument("--sas", action="store_true",
                      help="also write output.sas: the task in Fast Downward's own input language, each model "
                           "variable one multi-valued variable (docs/pddl.md)")
    pddl.set_defaults(func=cmd_export_pddl)
