"""Planner benchmark: `python tests/bench/bench_planner.py [--quick] [--runs N] [--members WORDS] [--limit S]`.

Prints, side by side in one run:

1. a row per planner member on each case: the portfolio's first plan (satisficing,
   what the controller gets first) and its final plan (after A* tried to improve it,
   marked minimal when shown), A* alone, the symbolic member alone, and breadth-first
   (given up at a state limit), and Fast Downward on the task exported to PDDL (docs/pddl.md), its
   satisficing search (greedy, FF), its optimal one (A* with h^max) and its optimal ones on the flat
   flavour without derived predicates (A* with lm-cut, with merge-and-shrink), and on the task written in
   SAS+ (multi-valued variables, no translator) its satisficing search and SymK's symbolic optimal one,
   and SymK on that task relaxed onto the variables the portfolio's plan writes (a lower bound, "yes" when it
   is the plan's length) (CPU time with that of its processes, the encoding and the translation included). Cases: the
   reference station (`engine_assembly`, with its synthesized supervisor) — `TightenBolt7` with the
   filter tool at home, 24 bolts from the frame placed, the `ParkNutrunner + AttachFilterTool + 3 filters + 2 pipes`
   goal set, `RobotHome` from the state where the old planner stalled
   (`robothome_state.toml`) — each other station's goal set at its start, and the
   synthetic N-bolt station for N = 4 … 96. Cold: a new goal set on a planner whose
   model tables are built (what the controller's planner process has after start-up;
   building them is printed per model); warm: the same goal set asked again (what the
   controller sees when it replans).
2. (with --runs N) the goal sets the reference station asks during N in-process runs
   (seeds 1..N, A* improving each first plan within 20,000 expansions): time to the first
   valid plan (p50, p99, max) and how often the first plan was already a shortest one
   where the final one was shown minimal.

Times are process CPU time (`time.process_time`), so other work on a shared machine moves them
little; nothing is asserted; the load average is printed.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from common.model import Model, OperationState, Predicate, all_of, parse_predicate
from common.model.compiled import CompiledModel, State
from common.stations import engine_assembly, load_model
from controller.pddl import Flavour, encode
from controller.pddl.downward import Search, solve
from controller.pddl.projection import plan_variables, project
from controller.planner import Budget, NoPlan, Plan, Planner, breadth_first
from controller.planner.policy import VIRTUAL_BUDGET
from controller.planner.search import astar
from controller.planner.steps import stable_goal
from controller.stack import build_controller_stack
from deploy.local.statefile import load_state
from tests.stations import synthetic

HERE = Path(__file__).resolve().parent
OTHER_STATIONS = tuple(f"{HERE.parent.parent / 'examples' / name / 'model.py'}:build_model"
                       for name in ("machine_tending", "shared_workspace"))


def ms(seconds: float) -> str:
    return f"{seconds * 1000:.1f} ms" if seconds < 1 else f"{seconds:.2f} s"


def table(title: str, header: list[str], rows: list[list[str]]) -> None:
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(header)]
    print(f"\n{title}")
    print("  " + "  ".join(h.rjust(w) for h, w in zip(header, widths, strict=True)))
    print("  " + "  ".join("-" * w for w in widths))
    for row in rows:
        print("  " + "  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)))
    sys.stdout.flush()


@dataclass
class Case:
    name: str
    compiled: CompiledModel
    forbidden: Predicate | None
    start: State
    goals: Mapping[str, Predicate]

    def planner(self) -> Planner:
        """A planner as the controller's planner process has it after start-up: model tables built."""
        planner = Planner(self.compiled, self.forbidden)
        planner.prepare()
        return planner


@dataclass
class Outcome:
    seconds: float
    length: str
    minimal: str
    expanded: str


def outcome(seconds: float, result: Plan | NoPlan | None, expanded: int | None = None) -> Outcome:
    if isinstance(result, Plan):
        return Outcome(seconds, str(len(result.steps)), "yes" if result.stats.minimal else "-",
                       str(result.stats.expanded if expanded is None else expanded))
    return Outcome(seconds, "none", "-", "-" if expanded is None else str(expanded))


# --- members ---------------------------------------------------------------------------------
def first_plan(planner: Planner, case: Case, limit: float) -> Outcome:
    began = time.process_time()
    first = next(iter(planner.plan_anytime(case.start, case.goals, budget=Budget(
        first_expansions=10**9, improve_expansions=0, seconds=limit))))
    return outcome(time.process_time() - began, first)


def final_plan(planner: Planner, case: Case, limit: float) -> Outcome:
    budget = Budget(first_expansions=10**9, improve_expansions=10**9, seconds=limit, improve_seconds=limit)
    began = time.process_time()
    result = planner.plan(case.start, case.goals, budget=budget)
    return outcome(time.process_time() - began, result)


def astar_alone(planner: Planner, case: Case, limit: float) -> Outcome:
    began = time.process_time()
    goal = all_of(*case.goals.values())
    is_goal = stable_goal(case.compiled, case.compiled.predicate(goal), frozenset())
    heuristic = planner.heuristic(tuple(case.goals.values()))
    heuristic.prepare(case.start)
    found = astar(planner.step_system(frozenset()), case.start, is_goal, planner.is_forbidden, heuristic,
                  time.perf_counter() + limit)
    seconds = time.process_time() - began
    if found.moves is None:
        return Outcome(seconds, "none" if not found.timed_out else f">{limit:.0f} s", "-", str(found.expanded))
    return Outcome(seconds, str(len(found.moves)), "yes", str(found.expanded))


def symbolic_alone(planner: Planner, case: Case, limit: float) -> Outcome:
    began = time.process_time()
    member = planner.symbolic(frozenset())
    if member is None:
        return Outcome(0.0, "n/a", "-", "-")
    found = member.search(case.start, all_of(*case.goals.values()), deadline=time.perf_counter() + limit)
    seconds = time.process_time() - began
    if found.moves is None:
        return Outcome(seconds, f">{limit:.0f} s" if found.timed_out else "none", "-", f"{found.layers} layers")
    return Outcome(seconds, str(len(found.moves)), "yes", f"{found.layers} layers")


def bfs_alone(case: Case, limit_states: int) -> Outcome:
    began = time.process_time()
    result = breadth_first(case.compiled, case.start, all_of(*case.goals.values()), case.forbidden,
                           limit_states=limit_states)
    seconds = time.process_time() - began
    if isinstance(result, NoPlan):
        return Outcome(seconds, f"gave up ({limit_states} states)", "-", str(result.stats.generated))
    return Outcome(seconds, str(len(result.steps)), "yes", str(result.stats.generated))


def cpu_with_children() -> float:
    """This process's CPU time and that of its finished children (Fast Downward runs as two of them)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


def fast_downward(search: Search, flavour: Flavour = Flavour.AXIOMS) -> Callable[[Planner, Case, float], Outcome]:
    """Fast Downward (or SymK) on the exported task (docs/pddl.md): encoding, writing, translating and searching."""

    def run(planner: Planner, case: Case, limit: float) -> Outcome:
        began = cpu_with_children()
        task = encode(case.compiled, case.start, all_of(*case.goals.values()), case.forbidden)
        try:
            [answer] = solve(task, (search,), timeout=limit, flavour=flavour)
        except subprocess.TimeoutExpired:
            return Outcome(cpu_with_children() - began, f">{limit:.0f} s", "-", "-")
        seconds = cpu_with_children() - began
        if answer.plan is None:
            return Outcome(seconds, "none", "-", "-")
        return Outcome(seconds, str(len(answer.plan)), "yes" if search.optimal else "-", "-")

    return run


def symk_on_the_plans_variables(planner: Planner, case: Case, limit: float) -> Outcome:
    """SymK on the task relaxed onto the variables the portfolio's final plan writes (controller/pddl/projection.py):
    its optimum there is a lower bound, "yes" when it equals the plan's length (the plan is then shown shortest).
    The plan is made first and its time not counted."""
    goal = all_of(*case.goals.values())
    plan = planner.plan(case.start, case.goals, budget=Budget(first_expansions=10**9, improve_expansions=10**9,
                                                               seconds=limit, improve_seconds=limit))
    if not isinstance(plan, Plan):
        return Outcome(0.0, "n/a", "-", "-")
    began = cpu_with_children()
    task = project(encode(case.compiled, case.start, goal, case.forbidden), case.compiled,
                   plan_variables(case.compiled, plan, goal))
    try:
        [answer] = solve(task, (Search.SYMBOLIC,), timeout=limit, flavour=Flavour.SAS)
    except subprocess.TimeoutExpired:
        return Outcome(cpu_with_children() - began, f">{limit:.0f} s", "-", "-")
    seconds = cpu_with_children() - began
    if answer.plan is None:
        return Outcome(seconds, "none", "-", "-")
    return Outcome(seconds, str(len(answer.plan)), "yes" if len(answer.plan) == len(plan.steps) else "-", "-")


MEMBERS: list[tuple[str, Callable[[Planner, Case, float], Outcome]]] = [
    ("portfolio: first plan", first_plan),
    ("portfolio: final plan", final_plan),
    ("A* alone", astar_alone),
    ("symbolic alone", symbolic_alone),
    ("Fast Downward: satisficing", fast_downward(Search.SATISFICING)),
    ("Fast Downward: optimal", fast_downward(Search.OPTIMAL)),
    ("Fast Downward: optimal, flat, lm-cut", fast_downward(Search.LMCUT, Flavour.FLAT)),
    ("Fast Downward: optimal, flat, merge-and-shrink", fast_downward(Search.MERGE_AND_SHRINK, Flavour.FLAT)),
    ("Fast Downward: satisficing, SAS+", fast_downward(Search.SATISFICING, Flavour.SAS)),
    ("SymK: optimal (symbolic), SAS+", fast_downward(Search.SYMBOLIC, Flavour.SAS)),
    ("SymK: lower bound on the plan's variables, SAS+", symk_on_the_plans_variables),
]


SLOW = 3.0  # seconds
BUILDS: dict[int, str] = {}  # id(compiled) -> model tables build time, printed once per model


def bench_case(case: Case, limit: float, bfs_limit: int, repeats: int) -> list[list[str]]:
    rows = []
    if id(case.compiled) not in BUILDS:
        BUILDS[id(case.compiled)] = ms(Planner(case.compiled, case.forbidden).prepare())
        print(f"  {case.compiled.model.name}: model tables built in {BUILDS[id(case.compiled)]}", file=sys.stderr)
        rows.append([case.compiled.model.name, "(model tables, once at start-up)", BUILDS[id(case.compiled)],
                     "-", "-", "-", "-"])
    for member, run in MEMBERS:
        planner = case.planner()
        cold = run(planner, case, limit)
        warm_cell = "-"  # a member that needs seconds cold is not asked again: warm would say little more
        if cold.seconds < SLOW:
            warm = [run(planner, case, limit) for _ in range(repeats)]
            warm_cell = ms(statistics.median(w.seconds for w in warm))
        rows.append([case.name, member, ms(cold.seconds), warm_cell, cold.length, cold.minimal, cold.expanded])
        print(f"  {case.name} / {member}: {cold.length} steps, cold {ms(cold.seconds)}", file=sys.stderr)
    if bfs_limit:
        b = bfs_alone(case, bfs_limit)
        rows.append([case.name, "breadth-first", ms(b.seconds), "-", b.length, b.minimal, b.expanded])
    return rows


# --- cases -----------------------------------------------------------------------------------
def compiled_of(model: Model) -> tuple[CompiledModel, Predicate | None]:
    stack = build_controller_stack(model)
    return stack.compiled, stack.supervisor.forbidden


def walk(model: Model, compiled: CompiledModel, planner: Planner, names: list[str]) -> State:
    """Run operations one after another (one plan each, as the engine would) and return the state."""
    state = compiled.initial()
    for name in names:
        op = model.operation_by_name[name]
        state = compiled.with_values(state, {op.state_path: OperationState.EXECUTING.value})
        result = planner.plan(state, {name: op.goal}, budget=Budget(improve_expansions=0, seconds=60))
        if not isinstance(result, Plan):
            raise SystemExit(f"walk: no plan for {name}: {result.reason}")
        state, _ = compiled.close(result.states[-1])
        state = compiled.with_values(state, {op.state_path: OperationState.FINISHED.value})
    return state


def reference_cases() -> list[Case]:
    model = engine_assembly.build_model()
    compiled, forbidden = compiled_of(model)
    planner = Planner(compiled, forbidden)
    order = list(engine_assembly.OPERATION_ORDER)
    goals_of = {op.name: op.goal for op in model.operations}
    frame_placed = walk(model, compiled, planner, order[: order.index("LiftLadderFrame") + 1])
    bolts_placed = walk(model, compiled, planner, order[: order.index("PlaceBolts") + 1])
    holding = planner.plan(bolts_placed, {"filter tool at home": parse_predicate(
        "rsp.tool_m == filter_tool && ur.pos_m == home && ur.ref_pos_c == home")}, budget=Budget(seconds=60))
    assert isinstance(holding, Plan), holding
    bolts = {n: g for n, g in goals_of.items() if n.startswith("TightenBolt")}
    mounted = walk(model, compiled, planner, [*order[: order.index("TightenBolt24") + 1], "MountFilter1",
                                              "MountFilter2", "MountFilter3", "MountOilPipes"])
    park_set = ["ParkNutrunner", "AttachFilterTool", "TightenFilter1", "TightenFilter2", "TightenFilter3",
                "TightenPipe1", "TightenPipe2"]
    executing = {model.operation_by_name[n].state_path: OperationState.EXECUTING.value for n in park_set}
    robot_home = model.initial_state()
    robot_home.update(load_state(str(HERE / "robothome_state.toml"), model))
    return [
        Case("TightenBolt7 (filter tool at home)", compiled, forbidden, holding.states[-1],
             {"TightenBolt7": goals_of["TightenBolt7"]}),
        Case("24 bolts (frame placed)", compiled, forbidden, frame_placed, bolts),
        Case("Park+AttachFilterTool+3 filters+2 pipes", compiled, forbidden,
             compiled.with_values(mounted, executing), {n: goals_of[n] for n in park_set}),
        Case("RobotHome (where it stalled)", compiled, forbidden, compiled.pack(robot_home),
             {"RobotHome": goals_of["RobotHome"]}),
    ]


def station_cases() -> list[Case]:
    """Each other station: the goals of every operation whose precondition holds at the start."""
    cases = []
    for reference in OTHER_STATIONS:
        try:
            model = load_model(reference)
        except Exception as exc:  # a station not (yet) in this tree: say so, go on
            print(f"  {reference}: not benchmarked ({exc})", file=sys.stderr)
            continue
        compiled, forbidden = compiled_of(model)
        start = compiled.initial()
        state = compiled.unpack(start)
        goals = {op.name: op.goal for op in model.operations if op.pre.eval(state)}
        cases.append(Case(f"{model.name}: {len(goals)} goals at start", compiled, forbidden, start, goals))
    return cases


def synthetic_cases(sizes: list[int]) -> list[Case]:
    cases = []
    for n in sizes:
        model = synthetic.build_model(n)
        compiled = CompiledModel(model)
        cases.append(Case(f"synthetic N={n}", compiled, None, compiled.initial(),
                          {op.name: op.goal for op in model.operations}))
    return cases


# --- 2. goal sets asked during runs ----------------------------------------------------------------
def bench_runs(runs: int) -> None:
    from controller.planner.relaxed import Estimate, RelaxedPlan
    from deploy.local.inprocess import run_in_process

    firsts: list[float] = []
    heaviest: list[tuple[float, int, int]] = []  # (first plan process seconds, goals, relaxed evaluations)
    first_minimal = shown_minimal = requests = evaluations = 0
    original, evaluate = Planner.plan_anytime, RelaxedPlan.evaluate

    def counting(self: RelaxedPlan, state: State) -> Estimate:
        nonlocal evaluations
        evaluations += 1
        return evaluate(self, state)

    def recording(self: Planner, start: State, goals: Mapping[str, Predicate], disabled: frozenset[str] = frozenset(),
                  budget: Budget | None = None) -> Iterator[Plan | NoPlan]:
        nonlocal first_minimal, shown_minimal, requests
        began, evaluated = time.process_time(), evaluations
        answers: list[Plan | NoPlan] = []
        for answer in original(self, start, goals, disabled, budget):
            if not answers:
                firsts.append(time.process_time() - began)
                heaviest.append((firsts[-1], len(goals), evaluations - evaluated))
            answers.append(answer)
            yield answer
        requests += 1
        if isinstance(answers[-1], Plan) and answers[-1].stats.minimal:
            shown_minimal += 1
            if isinstance(answers[0], Plan) and len(answers[0].steps) == len(answers[-1].steps):
                first_minimal += 1

    Planner.plan_anytime = recording  # type: ignore[method-assign]  # counting, restored below
    RelaxedPlan.evaluate = counting  # type: ignore[method-assign]  # counting, restored below
    # A* may improve each first plan here (in-process runs keep the first by default), to count how
    # often the first plan was already a shortest one.
    budget = replace(VIRTUAL_BUDGET, improve_expansions=20_000)
    finished = 0
    began = time.process_time()
    try:
        for seed in range(1, runs + 1):
            summary = run_in_process(engine_assembly.build_model(), seed=seed, budget=budget)
            finished += summary.finished
            print(f"  run seed {seed}: {'finished' if summary.finished else 'NOT finished'} "
                  f"{summary.operations_finished}/{summary.operations_total}, {summary.plans} plans, "
                  f"wall {summary.wall_seconds:.1f} s", file=sys.stderr)
    finally:
        Planner.plan_anytime = original  # type: ignore[method-assign]  # restored
        RelaxedPlan.evaluate = evaluate  # type: ignore[method-assign]  # restored
    firsts.sort()
    worst = max(heaviest)
    p99 = firsts[min(len(firsts) - 1, int(len(firsts) * 0.99))]
    table(f"2. Goal sets the reference station asks, in-process runs seeds 1..{runs} "
          f"({finished}/{runs} finished, {time.process_time() - began:.0f} s)",
          ["requests", "first plan p50", "p99", "max (goals, relaxed evaluations)", "final shown minimal",
           "first already minimal"],
          [[str(requests), ms(statistics.median(firsts)), ms(p99), f"{ms(worst[0])} ({worst[1]}, {worst[2]})",
            str(shown_minimal), f"{first_minimal} ({100 * first_minimal / max(1, shown_minimal):.0f} %)"]])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer cases and repeats, short limits")
    parser.add_argument("--runs", type=int, default=0, help="also record the goal sets of N in-process runs")
    parser.add_argument("--only-runs", action="store_true", help="with --runs: skip the table of members")
    parser.add_argument("--members", default="", help="only the members whose name contains one of these "
                                                      "comma-separated words (e.g. 'SymK,portfolio')")
    parser.add_argument("--limit", type=float, default=0.0, help="seconds per member (default 30, --quick 5)")
    args = parser.parse_args()
    if args.members:
        words = [w.strip().lower() for w in args.members.split(",") if w.strip()]
        MEMBERS[:] = [(name, run) for name, run in MEMBERS if any(w in name.lower() for w in words)]
        if not MEMBERS:
            parser.error(f"--members {args.members!r} names no member")
    print(f"planner benchmark (python {sys.version.split()[0]}, {os.cpu_count()} cpu, "
          f"load average {os.getloadavg()[0]:.1f})")
    if args.only_runs:
        bench_runs(args.runs)
        return
    limit = args.limit or (5.0 if args.quick else 30.0)
    repeats = 1 if args.quick else 3
    rows: list[list[str]] = []
    for case in reference_cases():
        rows += bench_case(case, limit, 0 if args.quick else 300_000, repeats)
    for case in station_cases():
        rows += bench_case(case, limit, 0, repeats)
    sizes = [4, 12, 24] if args.quick else [4, 12, 24, 48, 96]
    for case in synthetic_cases(sizes):
        rows += bench_case(case, limit, 300_000 if case.name.endswith(("=4", "=12")) else 0, repeats)
    table(f"1. Planner members per case (limit {limit:.0f} s per member; warm = median of {repeats})",
          ["case", "member", "cold", "warm", "length", "minimal", "expanded"], rows)
    if args.runs:
        bench_runs(args.runs)
    print(f"\nload average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
