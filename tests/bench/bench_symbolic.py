"""Symbolic planner benchmark: `python tests/bench/bench_symbolic.py [--repeats N] [--robothome PATH]`.

Cases: (a) the reference station's TightenBolt7 from the filter tool at home and (b)
RobotHome from where it stalled (bench_planner's reference cases; --robothome PATH loads
that start from another state file), (c) the synthetic station, all bolts, N = 4, 12, 24. For each: the
encoding build, the first search on a fresh planner (median over repeats; wall and CPU
time: the machine may be shared), a replan from the middle of the plan with the goal's
backward layers kept, the plan length and layers (forward + backward), BDD nodes, and a
fresh `Planner.plan` (the portfolio) for comparison. Every plan is checked with `check_plan`. Nothing is asserted.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from common.model import Predicate, all_of
from common.model.compiled import CompiledModel, State
from controller.planner import Plan, Planner
from controller.planner.plans import PlanStats
from controller.planner.steps import RaceCheck, stable_goal
from controller.planner.symbolic import SymbolicPlanner
from controller.planner.symbolic_encoding import BACKEND
from controller.planner.validate import check_plan, plan_from_moves
from tests.bench.bench_planner import ms, reference_cases, table
from tests.stations import synthetic


def case(label: str, compiled: CompiledModel, forbidden: Predicate | None, start: State, goal: Predicate,
         repeats: int) -> list[str]:
    builds, walls, cpus = [], [], []
    result = planner = None
    for _ in range(repeats):
        began = time.perf_counter()
        planner = SymbolicPlanner(compiled, forbidden)
        builds.append(time.perf_counter() - began)
        cpu = time.process_time()
        result = planner.search(start, goal)
        cpus.append(time.process_time() - cpu)
        walls.append(result.seconds)
    assert result is not None and planner is not None
    length = "none" if result.moves is None else str(len(result.moves))
    replan = "-"
    if result.moves is not None:
        plan = plan_from_moves(compiled, start, result.moves, ("goal",), PlanStats("symbolic"))
        is_forbidden = compiled.predicate(forbidden) if forbidden is not None else None
        check_plan(compiled, start, plan, stable_goal(compiled, compiled.predicate(goal), frozenset()),
                   is_forbidden, frozenset(), "goal", RaceCheck(compiled))
        middle = plan.states[len(plan.states) // 2]
        again = planner.search(middle, goal)
        replan = f"{ms(again.seconds)} ({len(again.moves or ())})"
    reference = Planner(compiled, forbidden).plan(start, {"goal": goal})
    planner_cell = f"{ms(reference.stats.seconds)} ({len(reference.steps) if isinstance(reference, Plan) else 'none'})"
    print(f"  {label}: {length} steps, search {ms(statistics.median(walls))}", file=sys.stderr)
    return [label, ms(statistics.median(builds)), ms(statistics.median(walls)), ms(statistics.median(cpus)),
            length, f"{result.forward}+{result.backward}", str(result.nodes), replan, planner_cell]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--robothome", default="", help="a state file for (b) instead of bench_planner's")
    args = parser.parse_args()
    print(f"symbolic planner benchmark (backend {BACKEND}, python {sys.version.split()[0]}, {os.cpu_count()} cpu, "
          f"load average {os.getloadavg()[0]:.1f})")
    rows = []
    cases = {c.name.split(" ")[0]: c for c in reference_cases()}
    bolt7, robot_home = cases["TightenBolt7"], cases["RobotHome"]
    rows.append(case("(a) TightenBolt7, filter tool at home", bolt7.compiled, bolt7.forbidden, bolt7.start,
                     all_of(*bolt7.goals.values()), args.repeats))
    start = robot_home.start
    if args.robothome:
        from deploy.local.statefile import load_state

        model = robot_home.compiled.model
        start = robot_home.compiled.pack({**model.initial_state(), **load_state(args.robothome, model)})
    rows.append(case("(b) RobotHome, where it stalled", robot_home.compiled, robot_home.forbidden, start,
                     all_of(*robot_home.goals.values()), args.repeats))
    for n in (4, 12, 24):
        synthetic_model = synthetic.build_model(n)
        synthetic_compiled = CompiledModel(synthetic_model)
        goal = all_of(*(op.goal for op in synthetic_model.operations))
        rows.append(case(f"(c) synthetic N={n}, all bolts", synthetic_compiled, None, synthetic_compiled.initial(),
                         goal, args.repeats))
    table("Symbolic planner (fresh planner per search; medians)",
          ["case", "build", "search", "search CPU", "length", "layers f+b", "nodes", "replan (kept)", "Planner cold"],
          rows)
    print(f"\nload average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
