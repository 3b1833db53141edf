"""The console with 500 resources: what one redraw costs, headless, with a canned feed.

`python tests/bench/bench_console.py [RESOURCES]` — a station of RESOURCES resources (4
variables each), 200 operations and a 60-step plan. Each round changes what a busy
station changes between two redraws (a tenth of the resources' state ages, one hub
late, 20 values, a few operations and plan steps) and times the table update (`sync`, Python side) and
the whole frame (update plus Textual's render of what is in view). It prints figures,
it asserts nothing.
"""

from __future__ import annotations

import asyncio
import random
import statistics
import sys
import time
from pathlib import Path

import msgspec

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from common.config.modes import DeviceMode
from common.model import Kind, OperationState
from common.wire.ctl import (
    ConsoleReply,
    ConsoleRequest,
    OperationInfo,
    PlanDetails,
    PlanInfo,
    PlanStepInfo,
    ResourceHealthInfo,
    StateSnapshot,
    StatusMessage,
    done_mask,
)
from common.wire.selftest_report import DeviceReport, SelftestMessage
from controller.console.app import ConsoleApp
from controller.console.station import StationInfo

OPERATIONS = 200
PLAN_STEPS = 60
ROUNDS = 60
KINDS = (("run_c", Kind.COMMAND), ("run_m", Kind.MEASURED), ("tqr_m", Kind.MEASURED), ("count_e", Kind.ESTIMATED))
MOVING = (OperationState.EXECUTING, OperationState.FINISHED)  # the states a round moves operations to


class CannedFeed:
    """A station that changes a little every round, as `Feed` (controller/console/link.py)."""

    def __init__(self, resources: int, seed: int = 0) -> None:
        self.random = random.Random(seed)
        self.names = [f"r{i:03d}" for i in range(resources)]
        self.status: StatusMessage | None = StatusMessage(
            station="bench", controller="bench-0", time=time.time(), uptime=0.0,
            operations=[OperationInfo(f"Op{i}", OperationState.INITIAL) for i in range(OPERATIONS)],
            health=[ResourceHealthInfo(r, f"hub{i // 8}", True, age=0.01) for i, r in enumerate(self.names)],
            plan=PlanInfo(1, [f"Op{i}" for i in range(10)], PLAN_STEPS, done_mask((), PLAN_STEPS)),
            plans=1, replans=0, no_plans=0, abilities=0)
        self.plan: PlanDetails | None = PlanDetails(id=1, goals=[f"Op{i}" for i in range(10)], current=True, steps=[
            PlanStepInfo(self.names[j % resources], f"{self.names[j % resources]}.tighten.enabled",
                         "deliberate", f"!{self.names[j % resources]}.run_c && ur.pos_m == at_bolt{j}", False)
            for j in range(PLAN_STEPS)])
        self.snapshot: StateSnapshot | None = StateSnapshot(
            time=time.time(), values={f"{r}.{name}": False if name != "count_e" else 0
                                      for r in self.names for name, _ in KINDS})
        self.selftests = {f"hub{i}": SelftestMessage(hub=f"hub{i}", ok=True, time=time.time(), devices=[
            DeviceReport(r, True, []) for r in self.names[i * 8:(i + 1) * 8]]) for i in range((resources + 7) // 8)}
        self.version = 0
        self.connected = True

    async def run(self) -> None:
        await asyncio.get_running_loop().create_future()

    async def request(self, request: ConsoleRequest) -> ConsoleReply:
        return ConsoleReply(accepted=True)

    def step(self, round_: int) -> None:
        rnd = self.random
        status, snapshot = self.status, self.snapshot
        assert status is not None and snapshot is not None
        health = list(status.health)
        for i in rnd.sample(range(len(health)), len(health) // 10):
            health[i] = msgspec.structs.replace(health[i], age=rnd.random() * 0.4)
        late = rnd.randrange(len(health))  # one hub a round lags (its age shows in tenths)
        health[late] = msgspec.structs.replace(health[late], age=1.0 + rnd.random())
        operations = list(status.operations)
        for i in rnd.sample(range(len(operations)), 3):
            operations[i] = msgspec.structs.replace(operations[i], state=rnd.choice(MOVING),
                                                    since=round_ * 0.3)
        assert status.plan is not None  # the canned status has a plan
        plan = msgspec.structs.replace(status.plan, done=done_mask(range(round_ % PLAN_STEPS), PLAN_STEPS))
        self.status = msgspec.structs.replace(status, health=health, operations=operations, plan=plan,
                                              uptime=round_ * 0.3, time=time.time())
        values = dict(snapshot.values)
        for path in rnd.sample(sorted(values), 20):
            value = values[path]
            values[path] = value + 1 if isinstance(value, int) and not isinstance(value, bool) else not value
        self.snapshot = StateSnapshot(time=time.time(), values=values)
        self.version += 1


def station_info(feed: CannedFeed) -> StationInfo:
    kinds = {f"{r}.{name}": kind for r in feed.names for name, kind in KINDS}
    return StationInfo(station="bench", kinds=kinds, goals={f"Op{i}": f"r{i:03d}.tqr_m" for i in range(OPERATIONS)},
                       modes=dict.fromkeys(feed.names, DeviceMode.EMULATE))


async def measure(resources: int) -> None:
    feed = CannedFeed(resources)
    app = ConsoleApp(station_info(feed), feed, refresh_s=3600)  # the bench redraws by itself
    async with app.run_test(size=(200, 60)) as pilot:
        began = time.perf_counter()
        app.redraw(force=True)
        await pilot.pause()
        first = time.perf_counter() - began
        syncs, frames, cells = [], [], []
        for round_ in range(1, ROUNDS + 1):
            feed.step(round_)
            began = time.perf_counter()
            app.redraw()
            syncs.append(app.last_redraw_s)
            cells.append(app.last_changed)
            await pilot.pause()
            frames.append(time.perf_counter() - began)
        began = time.perf_counter()
        app.action_kind()  # a new filter reorders the state table: the one case that rebuilds it
        await pilot.pause()
        refilter = time.perf_counter() - began
    variables = len(feed.snapshot.values) if feed.snapshot else 0
    print(f"console: {resources} resources, {variables} variables, {OPERATIONS} operations, {PLAN_STEPS} plan steps "
          f"(200x60 terminal, headless)")
    print(f"  first draw (every row added)            {first * 1e3:8.1f} ms")
    for name, samples in (("table update per redraw (sync)", syncs), ("frame: update + render", frames)):
        samples.sort()
        print(f"  {name:<40} median {statistics.median(samples) * 1e3:6.1f} ms   "
              f"p99 {samples[int(len(samples) * 0.99)] * 1e3:6.1f} ms")
    print(f"  cells changed per redraw                 median {statistics.median(cells):6.0f}")
    print(f"  new kind filter (state table rebuilt)    {refilter * 1e3:8.1f} ms")


if __name__ == "__main__":
    asyncio.run(measure(int(sys.argv[1]) if len(sys.argv) > 1 else 500))
