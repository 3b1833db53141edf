"""Planner benchmark: `python tests/bench/bench_planner.py [--quick]`.

Prints three tables:

1. the synthetic N-bolt station (`common.stations.synthetic`): A* cold (a new Planner:
   projections and distance tables built) and warm (the same Planner again: what the
   controller sees when it replans), plan length, states expanded and generated, the
   heuristic build time, growth against the previous N, and the plain breadth-first
   baseline in the same run (time, length, states; it gives up at a state limit);
2. the reference station (`common.stations.engine_assembly`, with the synthesized
   supervisor): one operation's plan (TightenBolt7 with the robot holding the
   oil-filter tool at home) and all 24 bolts at once, from the state after the bolts
   are placed and from the state after the ladder frame is placed;
3. (not with --quick) the heuristic's parts switched off one by one, to show what each buys.

Medians over repeated warm runs; nothing is asserted. The load average is printed:
timings on a shared machine vary.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from common.model import Predicate, all_of, parse_predicate
from common.model.compiled import CompiledModel, State
from common.stations import engine_assembly, synthetic
from controller.planner import HeuristicOptions, NoPlan, Plan, Planner, breadth_first
from controller.synthesis import synthesize


def timed(call: Callable[[], Plan | NoPlan]) -> tuple[float, Plan | NoPlan]:
    began = time.perf_counter()
    result = call()
    return time.perf_counter() - began, result


def ms(seconds: float) -> str:
    return f"{seconds * 1000:.1f} ms" if seconds < 1 else f"{seconds:.2f} s"


def length(result: Plan | NoPlan) -> str:
    return str(len(result.steps)) if isinstance(result, Plan) else "none"


def table(title: str, header: list[str], rows: list[list[str]]) -> None:
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(header)]
    print(f"\n{title}")
    print("  " + "  ".join(h.rjust(w) for h, w in zip(header, widths, strict=True)))
    print("  " + "  ".join("-" * w for w in widths))
    for row in rows:
        print("  " + "  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)))


# --- 1. synthetic --------------------------------------------------------------------------
def bench_synthetic(sizes: list[int], repeats: int, bfs_sizes: set[int], bfs_limit: int) -> None:
    rows = []
    previous: float | None = None
    for n in sizes:
        model = synthetic.build_model(n)
        compiled = CompiledModel(model)
        goals = {op.name: op.goal for op in model.operations}
        start = compiled.initial()
        planner = Planner(compiled)
        cold, result = timed(lambda p=planner, g=goals, s=start: p.plan(s, g, time_limit=300))
        warm = statistics.median(timed(lambda p=planner, g=goals, s=start: p.plan(s, g, time_limit=300))[0]
                                 for _ in range(repeats))
        growth = f"x{cold / previous:.1f}" if previous else "-"
        previous = cold
        bfs_cells = ["-", "-", "-", "-"]
        if n in bfs_sizes:
            bfs_time, baseline = timed(lambda c=compiled, s=start, g=goals: breadth_first(
                c, s, all_of(*g.values()), limit_states=bfs_limit))
            states = f"{baseline.stats.generated}"
            if isinstance(baseline, NoPlan):
                bfs_cells = [f">{ms(bfs_time)}", f"gave up ({bfs_limit} states)", states, f">x{bfs_time / warm:.0f}"]
            else:
                bfs_cells = [ms(bfs_time), length(baseline), states, f"x{bfs_time / warm:.0f}"]
        stats = result.stats
        rows.append([str(n), ms(cold), ms(warm), length(result), str(stats.expanded), str(stats.generated),
                     ms(stats.heuristic_seconds), growth, *bfs_cells])
        print(f"  synthetic N={n}: {length(result)} steps, cold {ms(cold)}, warm {ms(warm)}", file=sys.stderr)
    table("1. Synthetic N-bolt station (ring of 10 poses): all N bolts from the initial state",
          ["N", "A* cold", "A* warm", "length", "expanded", "generated", "h build", "growth",
           "BFS time", "BFS length", "BFS states", "BFS/A* warm"], rows)


# --- 2. reference station ------------------------------------------------------------------
class Reference:
    def __init__(self) -> None:
        model = engine_assembly.build_model()
        supervisor = synthesize(model)
        self.model = model
        self.forbidden = supervisor.forbidden
        self.compiled = CompiledModel(model, supervisor.guards)
        self.bolts = {f"TightenBolt{i}": model.operation_by_name[f"TightenBolt{i}"].goal
                      for i in engine_assembly.BOLTS}
        self.states = self._walk()

    def planner(self, options: HeuristicOptions | None = None) -> Planner:
        return Planner(self.compiled, self.forbidden, options=options)

    def _walk(self) -> dict[str, State]:
        """Run the operations in order (one plan each, as the engine would) and keep the scenario states."""
        compiled, planner = self.compiled, self.planner()
        state = compiled.initial()
        kept: dict[str, State] = {}
        for name in engine_assembly.OPERATION_ORDER[: engine_assembly.OPERATION_ORDER.index("PlaceBolts") + 1]:
            op = self.model.operation_by_name[name]
            state = compiled.with_values(state, {op.state_path: "executing"})
            result = planner.plan(state, {name: op.goal}, time_limit=120)
            if not isinstance(result, Plan):
                raise SystemExit(f"reference walk: no plan for {name}: {result.reason}")
            state, _ = compiled.close(result.states[-1])
            state = compiled.with_values(state, {op.state_path: "finished"})
            kept[name] = state
        holding = planner.plan(kept["PlaceBolts"], {"filter tool at home": parse_predicate(
            "rsp.tool_m == filter_tool && ur.pos_m == home && ur.ref_pos_c == home")}, time_limit=120)
        if not isinstance(holding, Plan):
            raise SystemExit(f"reference walk: cannot take the filter tool home: {holding.reason}")
        return {"frame placed": kept["LiftLadderFrame"], "bolts placed": kept["PlaceBolts"],
                "filter tool at home": holding.states[-1]}


def bench_reference(reference: Reference, repeats: int, quick: bool) -> None:
    bolt7 = {"TightenBolt7": reference.bolts["TightenBolt7"]}
    scenarios: list[tuple[str, str, Mapping[str, Predicate], int]] = [
        ("TightenBolt7", "filter tool at home", bolt7, repeats * 4),
        ("24 bolts", "bolts placed", reference.bolts, repeats),
    ]
    if not quick:
        scenarios.append(("24 bolts", "frame placed", reference.bolts, max(1, repeats // 2)))
    rows = []
    for label, where, goals, runs in scenarios:
        start = reference.states[where]
        planner = reference.planner()
        cold, result = timed(lambda p=planner, g=goals, s=start: p.plan(s, g, time_limit=300))
        warm_times = [timed(lambda p=planner, g=goals, s=start: p.plan(s, g, time_limit=300))[0]
                      for _ in range(runs)]
        stats = result.stats
        rows.append([label, where, ms(cold), ms(statistics.median(warm_times)), length(result),
                     str(stats.expanded), str(stats.generated), ms(stats.heuristic_seconds)])
        print(f"  reference {label} from {where}: {length(result)} steps, cold {ms(cold)}", file=sys.stderr)
    start = reference.states["filter tool at home"]
    bfs_time, baseline = timed(lambda: breadth_first(reference.compiled, start, bolt7["TightenBolt7"],
                                                     reference.forbidden, limit_states=300_000))
    gave_up = isinstance(baseline, NoPlan)
    rows.append(["TightenBolt7 (BFS)", "filter tool at home", (">" if gave_up else "") + ms(bfs_time), "-",
                 "gave up (300000 states)" if gave_up else length(baseline),
                 str(baseline.stats.expanded), str(baseline.stats.generated), "-"])
    table("2. Reference station (engine assembly, synthesized supervisor)",
          ["goal", "from", "cold", "warm (median)", "length", "expanded", "generated", "h build (cold)"], rows)


# --- 3. ablation ---------------------------------------------------------------------------------
def bench_ablation(reference: Reference) -> None:
    variants = [
        ("full", HeuristicOptions()),
        ("no potentials", HeuristicOptions(potential=0)),
        ("one pattern per family", HeuristicOptions(patterns=1)),
        ("no arborescence", HeuristicOptions(arborescence=False)),
        ("no enabling landmarks", HeuristicOptions(landmarks=False)),
        ("design note (1 pattern, no arb., no pot.)", HeuristicOptions(patterns=1, arborescence=False, potential=0)),
    ]
    model = synthetic.build_model(24)
    compiled = CompiledModel(model)
    synthetic_goals = {op.name: op.goal for op in model.operations}
    cases = [
        ("synthetic N=24", compiled, None, compiled.initial(), synthetic_goals),
        ("reference 24 bolts, bolts placed", reference.compiled, reference.forbidden,
         reference.states["bolts placed"], reference.bolts),
        ("reference 24 bolts, frame placed", reference.compiled, reference.forbidden,
         reference.states["frame placed"], reference.bolts),
    ]
    rows = []
    for case, comp, forbidden, start, goals in cases:
        for name, options in variants:
            planner = Planner(comp, forbidden, options=options)
            heuristic = planner.heuristic(tuple(goals.values()))
            heuristic.prepare(start)
            h0 = heuristic(start)
            _, result = timed(lambda p=planner, g=goals, s=start: p.plan(s, g, time_limit=20))
            warm, again = timed(lambda p=planner, g=goals, s=start: p.plan(s, g, time_limit=20))
            rows.append([case, name, str(h0), length(result), str(result.stats.expanded),
                         ms(warm) if isinstance(again, Plan) else ">20 s"])
            print(f"  ablation {case} / {name}: h0={h0}, {length(result)}", file=sys.stderr)
    table("3. What each part of the heuristic buys (h at the start vs plan length; warm time, 20 s limit)",
          ["case", "heuristic", "h(start)", "length", "expanded", "warm"], rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer sizes and repeats; under a minute")
    args = parser.parse_args()
    print(f"planner benchmark (python {sys.version.split()[0]}, {os.cpu_count()} cpu, "
          f"load average {os.getloadavg()[0]:.1f})")
    if args.quick:
        bench_synthetic([4, 12, 24], repeats=3, bfs_sizes={4}, bfs_limit=300_000)
    else:
        bench_synthetic([4, 12, 24, 48, 96], repeats=5, bfs_sizes={4, 12}, bfs_limit=2_000_000)
    reference = Reference()
    bench_reference(reference, repeats=3 if args.quick else 5, quick=args.quick)
    if not args.quick:
        bench_ablation(reference)
    print(f"\nload average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
