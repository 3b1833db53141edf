"""The live station as a new user meets it: `python tests/bench/bench_live_planning.py [--seeds 1-10]
[--config hubs.toml] [--mode emulate|sim]`.

Runs `hubctl up --seed N` once per seed (the controller, its planner process and every hub as separate
processes over Zenoh on loopback, wall-clock planning limits: what `./dev up` runs) and prints, per run
and over all runs:

* whether it finished, its station time, operations, plans, replans, goals without a plan;
* for every plan request the controller made, the time from the request to its first answer **as the
  controller saw it** (its own clock in the run's recording: the planner's work, the pipe both ways and
  any wait for the planner process), and the planner's own wall time for that answer; p50, p99, max.

Nothing is asserted. Load average is printed: a loaded machine starves the processes and every wall-clock
figure with them, so quote figures from a quiet machine.
"""

from __future__ import annotations

import argparse
import os
import re
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import msgspec

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from controller.recording.schema import PlanRecord  # noqa: E402
from controller.recording.writer import RECORDING_DIR_ENV  # noqa: E402
from tests.bench.bench_seeds import seeds_of  # noqa: E402

RUN_LIMIT_S = 300.0
SUMMARY = re.compile(r"^(finished|stopped|stuck).*$", re.MULTILINE)


def quantile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))] if ordered else float("nan")


Answered = tuple[float, float, int, str, str]  # latency ms, the planner's own ms, goals, why asked, member


def first_answers(recording: Path) -> list[Answered]:
    """(request -> first answer on the controller's clock in ms, the planner's own ms, goals, the request's
    reason, the member that answered) per request."""
    asked: dict[str, float] = {}
    found = []
    with sqlite3.connect(recording) as db:
        rows = db.execute("SELECT t, kind, key, data FROM events WHERE kind IN ('plan_request', 'plan') ORDER BY id")
        for t, kind, key, data in rows:
            if kind == "plan_request":
                asked[key] = t
                continue
            record = msgspec.msgpack.decode(data, type=PlanRecord)
            if record.answer == "first" and record.goals and key in asked:
                found.append((1000 * (t - asked.pop(key)), record.ms, len(record.goals), record.reason,
                              record.member))
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="1-10")
    parser.add_argument("--config", default=str(ROOT / "hubs.toml"))
    parser.add_argument("--mode", default="emulate")
    args = parser.parse_args()
    hubctl = Path(sys.executable).with_name("hubctl")
    latencies: list[float] = []
    own: list[float] = []
    slowest: list[tuple[Answered, int]] = []
    finished = 0
    seeds = seeds_of(args.seeds)
    with tempfile.TemporaryDirectory(prefix="bench-live-") as tmp:
        for seed in seeds:
            runs = Path(tmp) / f"seed{seed}"
            env = {**os.environ, RECORDING_DIR_ENV: str(runs)}
            began = time.monotonic()
            done = subprocess.run([str(hubctl), "up", "--config", args.config, "--mode", args.mode,
                                   "--seed", str(seed)], cwd=ROOT, env=env, capture_output=True, text=True,
                                  timeout=RUN_LIMIT_S)
            wall = time.monotonic() - began
            summary = SUMMARY.findall(done.stdout)
            line = SUMMARY.search(done.stdout)
            text = line.group(0) if line else f"no summary (exit {done.returncode}): {done.stderr[-300:]}"
            finished += bool(summary and summary[-1] == "finished")
            recordings = sorted(runs.glob("*.sqlite"))
            answers = first_answers(recordings[-1]) if recordings else []
            for answer in answers:
                latencies.append(answer[0])
                own.append(answer[1])
                slowest.append((answer, seed))
            seed_worst = max((a[0] for a in answers), default=float("nan"))
            print(f"seed {seed:3d}: {text} (wall {wall:.1f} s); {len(answers)} plan requests, "
                  f"first answer max {seed_worst:.1f} ms", flush=True)
    print(f"\n{finished} of {len(seeds)} runs finished")
    print(f"{len(latencies)} plan requests: request -> first answer (controller's clock) "
          f"p50 {quantile(latencies, 0.5):.1f} ms, p99 {quantile(latencies, 0.99):.1f} ms, "
          f"max {max(latencies, default=float('nan')):.1f} ms; "
          f"the planner's own time p50 {quantile(own, 0.5):.1f} ms, p99 {quantile(own, 0.99):.1f} ms")
    print("the slowest first answers:")
    for (latency, planner_ms, goals, reason, member), seed in sorted(slowest, reverse=True)[:5]:
        print(f"  {latency:6.1f} ms ({planner_ms:.1f} ms in the planner): {goals} goals, {reason}, by {member}, "
              f"seed {seed}")
    print(f"load average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
