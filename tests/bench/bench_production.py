"""Production figures (issue 22): `python tests/bench/bench_production.py [--processes] [--rss] [--long]
[--seeds 1-20] [--orders 200] [--jobs 2]`.

* `--processes`: `hubctl up --orders 5 --mix full:1,light:1` over real processes (emulated devices, speed 1):
  its engines per hour and cycle time p50/p95/max per variant, as it prints them.
* in process (always): `--orders` orders of full:1,light:1, seed 1, virtual time: the same figures, and the
  wall time per order. `--baseline`: the same run again with the timed check remembering no verdict
  (controller/timed_check.py `CHECKS_KEPT` = 0), and the ratio of the CPU times.
* `--rss`: the controller's resident memory (VmRSS) in a subprocess running the in-process station, after 10
  and after 200 orders, and their ratio (the issue asks within 10 %).
* `--long`: 200 orders for each seed of `--seeds`, nominal and with the nutrunner failing a fifth of its
  tightenings (`--fail-rate 0.2`), each checked as tests/test_production_long.py checks its 3 seeds (each
  operation once per order, no physical work twice): how many passed and the wall time of the whole set.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

REFERENCE = "common.stations.engine_assembly:build_model"
MIX = {"full": 1, "light": 1}
FAIL_RATE = 0.2
RSS_EARLY, RSS_LATE = 10, 200


def seeds_of(text: str) -> list[int]:
    seeds: list[int] = []
    for part in text.split(","):
        low, _, high = part.partition("-")
        seeds += list(range(int(low), int(high or low) + 1))
    return seeds


def over_processes() -> None:
    hubctl = ROOT / ".venv" / "bin" / "hubctl"
    began = time.perf_counter()
    done = subprocess.run([str(hubctl), "up", "--orders", "5", "--mix", "full:1,light:1"], cwd=ROOT,
                          capture_output=True, text=True, timeout=1800, check=False)
    wall = time.perf_counter() - began
    lines = [line for line in done.stdout.splitlines()
             if line.startswith(("finished:", "throughput:", "  cycle time")) or " done: cycle " in line]
    print(f"over processes (hubctl up --orders 5 --mix full:1,light:1): exit {done.returncode}, {wall:.0f} s wall")
    for line in lines:
        print("  " + line.strip())


def in_process(orders: int) -> float:
    from common.config.production import ProductionPlan, mixed
    from common.stations import load_model
    from controller.production.throughput import summary_lines
    from deploy.local.inprocess import run_in_process

    model = load_model(REFERENCE)
    began = time.perf_counter()
    cpu = time.process_time()
    summary = run_in_process(model, seed=1, production=ProductionPlan(mixed(MIX, orders), "bench"),
                             time_limit=orders * 600.0)
    wall, cpu = time.perf_counter() - began, time.process_time() - cpu
    print(f"in process ({orders} orders, seed 1, virtual time): {summary.outcome.value}, {wall:.1f} s wall, "
          f"{cpu:.1f} s CPU ({cpu / orders * 1000:.0f} ms an order, start-up included)")
    assert summary.throughput is not None
    for line in summary_lines(summary.throughput):
        print("  " + line)
    return cpu


def without_remembered_checks(orders: int, cpu: float) -> None:
    import controller.timed_check as timed_check

    kept, timed_check.CHECKS_KEPT = timed_check.CHECKS_KEPT, 0
    try:
        print("baseline: the timed check remembering no verdict")
        baseline = in_process(orders)
    finally:
        timed_check.CHECKS_KEPT = kept
    print(f"CPU with the timed check's memory / without: {cpu:.1f} / {baseline:.1f} s = {cpu / baseline:.2f}")


RSS_CHILD = """
import sys
sys.path.insert(0, {root!r})
from common.config.production import ProductionPlan, mixed
from common.stations import load_model
from deploy.local.inprocess import run_in_process

def rss_kib():
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith("VmRSS:"))

finished = 0
def report(line):
    global finished
    if " done: cycle " in line:
        finished += 1
        if finished in ({early}, {late}):
            print(finished, rss_kib(), flush=True)

model = load_model({reference!r})
run_in_process(model, seed=1, production=ProductionPlan(mixed({mix!r}, {late}), "bench"), time_limit={late} * 600.0,
               report=report)
"""


def rss() -> None:
    """The in-process station's resident memory after 10 and after 200 orders (a process of its own: the
    figure is the controller's and the emulated devices', nothing of this script's)."""
    child = RSS_CHILD.format(root=str(ROOT), reference=REFERENCE, mix=MIX, early=RSS_EARLY, late=RSS_LATE)
    done = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True, timeout=7200, check=True)
    figures: dict[int, int] = {}
    for line in done.stdout.splitlines():
        if line.strip():
            orders, kib = line.split()
            figures[int(orders)] = int(kib)
    early, late = figures[RSS_EARLY], figures[RSS_LATE]
    print(f"RSS of the in-process station: after {RSS_EARLY} orders {early / 1024:.1f} MiB, after {RSS_LATE} "
          f"{late / 1024:.1f} MiB: ratio {late / early:.3f} ({'within' if late <= early * 1.1 else 'NOT within'} 10 %)")


def long_run(seed: int, fail_rate: float, orders: int) -> tuple[int, float, str]:
    from common.stations import load_model
    from tests.test_production_long import assert_each_operation_once_per_order, run_orders

    model = load_model(REFERENCE)
    began = time.perf_counter()
    try:
        assert_each_operation_once_per_order(model, run_orders(model, orders, seed, fail_rate), orders)
    except AssertionError as exc:
        return seed, time.perf_counter() - began, f"FAILED: {str(exc).splitlines()[0]}"
    return seed, time.perf_counter() - began, "ok"


def long_set(seeds: list[int], orders: int, jobs: int, fail_rates: list[float]) -> None:
    for fail_rate in fail_rates:
        began = time.perf_counter()
        with concurrent.futures.ProcessPoolExecutor(jobs) as pool:
            results = list(pool.map(long_run, seeds, [fail_rate] * len(seeds), [orders] * len(seeds)))
        wall = time.perf_counter() - began
        failed = [(seed, note) for seed, _, note in results if note != "ok"]
        slowest = max(seconds for _, seconds, _ in results)
        print(f"{orders} orders x {len(seeds)} seeds, fail rate {fail_rate}: {len(seeds) - len(failed)} passed, "
              f"{wall:.0f} s wall on {jobs} processes (slowest seed {slowest:.0f} s)")
        for seed, note in failed:
            print(f"  seed {seed}: {note}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--processes", action="store_true", help="also hubctl up --orders 5 over real processes")
    parser.add_argument("--rss", action="store_true", help="also the RSS after 10 and after 200 orders")
    parser.add_argument("--long", action="store_true", help="also 200 orders for each seed, with and without failures")
    parser.add_argument("--seeds", default="1-20")
    parser.add_argument("--orders", type=int, default=200)
    parser.add_argument("--fail-rates", default=f"0,{FAIL_RATE}",
                        help="the --long halves to run, comma-separated (default %(default)s)")
    parser.add_argument("--baseline", action="store_true", help="also the in-process run without remembered checks")
    parser.add_argument("--jobs", type=int, default=max(1, min(2, os.cpu_count() or 1)))
    args = parser.parse_args()
    try:
        fail_rates = [float(rate) for rate in args.fail_rates.split(",")]
    except ValueError:
        parser.error(f"--fail-rates {args.fail_rates!r}: expected numbers separated by commas, e.g. 0,{FAIL_RATE}")
    if args.processes:
        over_processes()
    cpu = in_process(args.orders)
    if args.baseline:
        without_remembered_checks(args.orders, cpu)
    if args.rss:
        rss()
    if args.long:
        long_set(seeds_of(args.seeds), args.orders, args.jobs, fail_rates)


if __name__ == "__main__":
    main()
