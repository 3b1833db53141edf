"""Seed sweep: `python tests/bench/bench_seeds.py [--seeds 1-200] [--fail-rate P] [--model M] [--jobs J]
[--improve-expansions N]`.

Runs a station in process (virtual time, counted planning budgets) once per seed, as
`hubctl up --in-process --seed N` does, and prints one line per seed and a summary: how
many finished, station time and wall time (median, max), plans and replans. A seed that
does not finish is printed with its reason; rerun it with `hubctl up --in-process --seed N`
to see the whole run: it is the same run on any machine.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from common.stations import DEFAULT_MODEL, load_model


def seeds_of(text: str) -> list[int]:
    seeds: list[int] = []
    for part in text.split(","):
        low, _, high = part.partition("-")
        seeds += list(range(int(low), int(high or low) + 1))
    return seeds


def run_one(model_reference: str, seed: int, fail_rate: float,
            improve: int) -> tuple[int, bool, str, float, float, int, int]:
    from dataclasses import replace

    from controller.planner.policy import VIRTUAL_BUDGET
    from deploy.local.inprocess import run_in_process

    model = load_model(model_reference)
    failure = {"nr": fail_rate} if fail_rate else None
    summary = run_in_process(model, seed=seed, failure=failure,
                             budget=replace(VIRTUAL_BUDGET, improve_expansions=improve))
    return (seed, summary.finished, summary.reason, summary.emulated_seconds, summary.wall_seconds, summary.plans,
            summary.replans)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="1-20")
    parser.add_argument("--fail-rate", type=float, default=0.0)
    parser.add_argument("--model", default=DEFAULT_MODEL)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--improve-expansions", type=int, default=0, help="as `hubctl up --in-process`")
    args = parser.parse_args()
    seeds = seeds_of(args.seeds)
    print(f"seed sweep: {args.model}, seeds {args.seeds}, fail rate {args.fail_rate}, {args.jobs} job(s), "
          f"load average {os.getloadavg()[0]:.1f}", flush=True)
    began = time.perf_counter()
    results = []
    with concurrent.futures.ProcessPoolExecutor(args.jobs) as pool:
        futures = [pool.submit(run_one, args.model, seed, args.fail_rate, args.improve_expansions) for seed in seeds]
        for future in concurrent.futures.as_completed(futures):
            seed, finished, reason, station, wall, plans, replans = result = future.result()
            results.append(result)
            outcome = "finished" if finished else f"NOT finished: {reason}"
            print(f"  seed {seed:3d}: {outcome}, station {station:.1f} s, wall {wall:.1f} s, {plans} plans, "
                  f"{replans} replans", flush=True)
    done = [r for r in results if r[1]]
    print(f"\n{len(done)}/{len(results)} finished in {time.perf_counter() - began:.0f} s; "
          f"station time median {statistics.median(r[3] for r in results):.1f} s, "
          f"max {max(r[3] for r in results):.1f} s; "
          f"wall median {statistics.median(r[4] for r in results):.1f} s, max {max(r[4] for r in results):.1f} s; "
          f"replans median {statistics.median(r[6] for r in results):.0f}")
    failed = sorted(r[0] for r in results if not r[1])
    if failed:
        print(f"not finished: seeds {', '.join(map(str, failed))}")


if __name__ == "__main__":
    main()
