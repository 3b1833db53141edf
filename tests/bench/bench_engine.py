"""One engine tick on the reference station: median and p99, idle and while following a 24-bolt plan.

`python tests/bench/bench_engine.py` — the issue's target is a median under 1 ms.
"""

from __future__ import annotations

import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from common.model import parse_predicate
from common.stations.engine_assembly import BOLT_COUNT, build_model
from controller.engine import Engine, PlanProgress
from controller.planner import Plan
from controller.stack import build_controller_stack


def timed(fn: Callable[[], object], rounds: int) -> list[float]:
    samples = []
    for _ in range(rounds):
        began = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - began)
    return samples


def main() -> None:
    model = build_model()
    stack = build_controller_stack(model)
    compiled = stack.compiled
    engine = Engine(compiled)
    requested = [op.name for op in model.operations]
    bolts_placed = {f"engine.bolt{i}_e": "placed" for i in range(1, BOLT_COUNT + 1)}
    start = compiled.with_values(compiled.initial(), {
        **bolts_placed, "engine.frame_e": "placed", "rsp.tool_m": "nutrunner", "rsp.lock_c": True,
        "rsp.locked_m": True, "dock.nutrunner_home_m": False, "ur.pos_m": "above_engine",
        "ur.ref_pos_c": "above_engine"})
    goals = {f"TightenBolt{i}": parse_predicate(f"engine.bolt{i}_e == tightened") for i in range(1, BOLT_COUNT + 1)}
    plan = stack.planner.plan(start, goals)
    rows = []
    idle = timed(lambda: engine.tick(compiled.initial(), requested=requested), 2000)
    rows.append(("idle, all operations requested", idle))
    if isinstance(plan, Plan):
        def follow() -> None:
            progress = PlanProgress(compiled, plan)
            engine.tick(start, requested=requested, progress=progress)

        rows.append((f"first tick of a {len(plan.steps)}-step 24-bolt plan (incl. trace set-up)", timed(follow, 300)))
        progress = PlanProgress(compiled, plan)
        state = engine.tick(start, progress=progress).state
        rows.append(("tick while waiting on an effect, plan adopted",
                     timed(lambda: engine.tick(state, requested=requested, progress=progress), 2000)))
    print(f"engine tick on the reference station ({len(model.variables)} variables, "
          f"{len(compiled.transitions)} transitions)")
    print(f"  {'case':<62} {'median':>9} {'p99':>9}")
    for name, samples in rows:
        samples.sort()
        median, p99 = statistics.median(samples), samples[int(len(samples) * 0.99)]
        print(f"  {name:<62} {median * 1e3:7.3f} ms {p99 * 1e3:7.3f} ms")


if __name__ == "__main__":
    main()
