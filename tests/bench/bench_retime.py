"""The member that improves plans by time (controller/retime.py): cycle times in process without it and with it, in
the same run, on the reference station (both sets of durations, partial order), the two-jobs station
(tests/timing_stations/two_jobs.py) and random timed stations, with the member's CPU time per plan:
`.venv/bin/python tests/bench/bench_retime.py [random stations]`."""

from __future__ import annotations

import dataclasses
import statistics
import sys
import time
from collections.abc import Mapping
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from common.model import Model
from common.stations import load_model
from controller.deorder import Execution
from controller.planner.policy import VIRTUAL_BUDGET
from controller.retime import Retimer
from deploy.local.inprocess import run_in_process
from tests.stations.random_timed_station import build_random_timed_station
from tests.timing_stations.two_jobs import build_model

ISSUE_DELAYS = {"human": 20.0, "ur": 1.5, "nr": 2.0}  # issue 21: operator 20 s, ur 1.5 s, nr 2 s
WITHOUT = dataclasses.replace(VIRTUAL_BUDGET, retime_tries=0)

member_seconds: list[float] = []
_faster = Retimer.faster


def _timed_faster(*args: object, **kwargs: object) -> object:
    began = time.perf_counter()
    try:
        return _faster(*args, **kwargs)  # type: ignore[arg-type]
    finally:
        member_seconds.append(time.perf_counter() - began)


def cycles(model: Model, seed: int, delays: Mapping[str, float] | None = None) -> tuple[float, float]:
    """The cycle without the member and with it."""
    out = []
    for budget in (WITHOUT, VIRTUAL_BUDGET):
        summary = run_in_process(model, seed=seed, delays=delays, execution=Execution.PARTIAL_ORDER, budget=budget)
        assert summary.finished and summary.cycle is not None, summary.reason
        out.append(summary.cycle.cycle)
    return out[0], out[1]


def main() -> None:
    Retimer.faster = _timed_faster  # type: ignore[method-assign, assignment]
    randoms = int(sys.argv[1]) if len(sys.argv) > 1 else 40
    reference = load_model()
    for label, delays in (("default delays", None), ("issue 21 delays", ISSUE_DELAYS)):
        for seed in (1, 2, 3):
            before, after = cycles(reference, seed, delays)
            print(f"reference, {label:15} seed {seed}: cycle {before:6.1f} s -> {after:6.1f} s "
                  f"({after / before:5.3f})", flush=True)
    before, after = cycles(build_model(), 1)
    print(f"two jobs:                          cycle {before:6.1f} s -> {after:6.1f} s ({after / before:5.3f})")
    ratios = []
    for seed in range(randoms):
        before, after = cycles(build_random_timed_station(seed), seed)
        ratios.append(after / before)
    faster = sum(1 for r in ratios if r < 0.999)
    slower = sum(1 for r in ratios if r > 1.001)
    print(f"{randoms} random timed stations: cycle with/without the member mean {statistics.mean(ratios):5.3f}, "
          f"best {min(ratios):5.3f}, worst {max(ratios):5.3f}; {faster} faster, {slower} slower")
    ms = sorted(s * 1000 for s in member_seconds)
    print(f"the member's CPU time per plan (remembered ones included; virtual budget, {len(ms)} plans): "
          f"p50 {statistics.median(ms):.1f} ms, "
          f"p90 {ms[int(0.9 * (len(ms) - 1))]:.1f} ms, max {ms[-1]:.1f} ms")


if __name__ == "__main__":
    main()
