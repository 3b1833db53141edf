"""`{station}/ctl/status` carries what changed; the plan's steps come from `{station}/ctl/plan/{id}`.

The controller's `StatusDiet` turns full pictures into deltas, `StatusView` turns them back; a
reference run over the in-memory bus (its first RUN_OPERATIONS operations, at SPEED: more changes
per status than at speed 1) bounds the bytes the status costs per publication (so per second: it is
published every STATUS_PERIOD_S), and a console that connects late gets the whole
picture and the plan's details by asking.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable

import msgspec

from common.bus.memory_bus import MemoryBus
from common.model import OperationState
from common.wire.ctl import (
    ConsoleEvent,
    HubGone,
    OperationInfo,
    PlanInfo,
    ResourceHealthInfo,
    StatusMessage,
    done_mask,
)
from controller.console.statusview import StatusFollower, StatusView, fetch_plan
from controller.events import EventLog
from controller.statusfeed import StatusDiet
from controller.statuspublisher import STATUS_PERIOD_S
from tests.test_memory_station import REFERENCE, MemoryStation, station_at  # noqa: F401  (fixture)

BUDGET_BYTES_PER_S = 20_000  # the bound on ctl/status during a reference run
# The planner's searches, not the devices, are most of the run's time. At 20 times real speed on a machine with
# three CPU-bound processes per core, the measured state lagged the devices by seconds of their time, each plan
# was stale on arrival, and the replans undid each other until the livelock watch stopped the run (both seen in
# fresh-clone suites); at 5 the lag is a quarter of that and the 20 operations take about 3 s of station time.
SPEED = 5.0
RUN_OPERATIONS = 20


def picture(uptime: float, ops: dict[str, OperationState], ages: dict[str, float | None], plan: PlanInfo,
            events: list[ConsoleEvent]) -> StatusMessage:
    return StatusMessage(
        station="s", controller="c-1", time=uptime, uptime=uptime,
        operations=[OperationInfo(name, state) for name, state in ops.items()],
        health=[ResourceHealthInfo(r, "hub", age is not None, "" if age is not None else "not alive", age)
                for r, age in ages.items()],
        plan=plan, events=events[-20:])


def test_deltas_merge_back_into_the_full_pictures_and_carry_only_what_changed() -> None:
    diet, view = StatusDiet(full_every_s=100.0), StatusView()
    ops = {f"Op{i}": OperationState.INITIAL for i in range(30)}
    ages: dict[str, float | None] = {f"r{i}": 0.02 for i in range(10)}
    log = EventLog()
    plan = PlanInfo(1, ["Op3"], 40, done_mask((), 40))
    sizes = []
    for t in range(60):
        if t % 7 == 3:
            ops[f"Op{t % 30}"] = OperationState.EXECUTING
        if t == 20:
            ages["r4"] = None
            log.emit(HubGone("hub"))
        ages["r1"] = 0.01 * (t % 5)  # fresh: shown "< 1 s" whatever the exact age, so never resent
        plan = msgspec.structs.replace(plan, done=done_mask(range(t % plan.steps), plan.steps)) if t % 3 else plan
        if t == 40:
            plan = PlanInfo(2, ["Op3", "Op5"], 12, done_mask((), 12))
        whole = picture(float(t), ops, ages, plan, log.recent(20))
        sent = diet.next(whole, log, now=float(t))
        sizes.append(len(msgspec.msgpack.encode(sent)))
        merged = view.apply(msgspec.msgpack.decode(msgspec.msgpack.encode(sent), type=StatusMessage))
        assert merged is not None
        assert merged.operations == whole.operations and merged.plan == whole.plan and merged.events == log.recent(20)
        assert [(h.resource, h.healthy) for h in merged.health] == [(h.resource, h.healthy) for h in whole.health]
        if t:
            assert not sent.full and {op.name for op in sent.operations} <= {f"Op{t % 30}"}
            assert [h.resource for h in sent.health] == (["r4"] if t == 20 else [])
            assert sent.events == ([HubGone("hub")] if t == 20 else [])
    assert max(sizes[1:]) < sizes[0] / 3, sizes


def test_a_missed_delta_is_mended_by_the_full_picture_and_an_older_one_is_ignored() -> None:
    diet, view = StatusDiet(full_every_s=100.0), StatusView()
    ops = {"A": OperationState.INITIAL, "B": OperationState.INITIAL}
    plan = PlanInfo(0)
    first = diet.next(picture(0.0, ops, {}, plan, []), EventLog(), 0.0)
    assert view.apply(first) == first
    ops["B"] = OperationState.EXECUTING
    diet.next(picture(1.0, ops, {}, plan, []), EventLog(), 1.0)  # missed
    ops["A"] = OperationState.EXECUTING
    third = diet.next(picture(2.0, ops, {}, plan, []), EventLog(), 2.0)
    assert [op.name for op in third.operations] == ["A"]  # B changed in the missed one, not since
    assert view.apply(third) is None and view.needs_full
    assert diet.last_full is not None
    mended = view.apply(diet.last_full)  # what a query on the status key answers
    assert mended is not None and not view.needs_full
    assert {op.state for op in mended.operations} == {OperationState.EXECUTING}
    assert view.apply(first) is None  # late, older than the picture held


async def test_a_reference_run_costs_less_than_the_budget_and_a_late_console_gets_the_plan_by_asking(
        station_at: Callable[..., Awaitable[MemoryStation]]) -> None:  # noqa: F811  (the fixture)
    station = await station_at(REFERENCE, speed=SPEED)
    wire = await MemoryBus(station.network).open()
    sizes: list[int] = []
    fulls = 0
    samples = wire.subscribe(station.keys.ctl("status"), coalesce=False, maxlen=None)

    async def count() -> None:
        nonlocal fulls
        async for sample in samples:
            sizes.append(len(sample.payload))
            fulls += msgspec.msgpack.decode(sample.payload, type=StatusMessage).full

    counting = asyncio.create_task(count())
    try:
        # A console that connects once the station is under way: the whole picture and the plan's details at once.
        await station.wait_for(lambda: len(station.finished_operations()) >= 2, "two operations finish", 120)
        late = await MemoryBus(station.network).open()
        follower = StatusFollower(late, station.keys)
        statuses = late.subscribe(station.keys.ctl("status"), coalesce=False)
        status = None
        while status is None or not status.plan or not status.plan.id:
            status = await follower.take((await asyncio.wait_for(statuses.get(), 5.0)).payload)
        assert status.full and len(status.operations) == len(station.model.operations)
        assert {h.resource for h in status.health} == set(station.config.resources)
        details = await fetch_plan(late, station.keys, status.plan.id)
        assert details is not None and details.id == status.plan.id and details.goals == status.plan.goals
        assert len(details.steps) == status.plan.steps and all(step.guard for step in details.steps)
        transitions = {t.name for t in station.model.transitions}
        assert {step.transition for step in details.steps} <= transitions
        assert await fetch_plan(late, station.keys, status.plan.id + 1000) is None  # no such plan: no answer
        await late.close()

        # Its first RUN_OPERATIONS operations (the planner's own searches later take a minute on a loaded machine):
        # the plans for all the goals, the bolts placed and tightened, the operator's tasks, at SPEED.
        await station.wait_for(lambda: len(station.finished_operations()) >= RUN_OPERATIONS,
                               f"{RUN_OPERATIONS} operations finish", 300)
    finally:
        counting.cancel()
        await wire.close()
    assert station.all_healthy(), station.health()
    # Bytes, not time: the status goes out every STATUS_PERIOD_S, so its mean size bounds the bytes per second.
    per_second = sum(sizes) / len(sizes) / STATUS_PERIOD_S
    assert per_second < BUDGET_BYTES_PER_S, (per_second, max(sizes), len(sizes), fulls)
    assert fulls < len(sizes) / 10, (fulls, len(sizes))
