"""Orders in the control loop (issue 22, items 1-3 end to end): engine after engine, each operation once per order.

The loop finishes the running order once every operation it requests is finished, resets the product (recorded
as a `restore` and the operations' finished -> initial) and starts the next; the checks read the run's
recording: between one order's start and the next, each operation of its variant finished exactly once and no
other. In process (virtual time) and over real processes (`run_station`), where a client of its own adds and
cancels orders while the station runs. The long runs in process (200 orders a seed) are
tests/test_production_long.py's.
"""

from __future__ import annotations

import asyncio
import re
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import pytest

from common.bus.zenoh_bus import ZenohBus
from common.config.hubs_toml import load_station
from common.config.production import PlannedOrder, ProductionPlan, mixed
from common.model import Model, OperationState
from common.stations import load_model
from common.wire.ctl import OrderFinished, OrderStarted, ProductionInfo, StatusMessage
from common.wire.keys import Keys
from common.wire.messages import decode, encode
from common.wire.orders import OrdersAction, OrdersReply, OrdersRequest, OrderState
from controller.production.client import ask_orders
from controller.recording.reader import Record, open_run
from controller.recording.schema import OperationRecord, RecordKind, RestoreRecord
from controller.recording.writer import RECORDING_DIR_ENV
from deploy.local.done_once import DoneOnce, check_done_once, count_finishes, run_recordings
from deploy.local.inprocess import run_in_process
from deploy.local.localcerts import watcher_zenoh_config
from deploy.local.station import Options, run_station
from deploy.replay.replay import ListSink

REFERENCE = "common.stations.engine_assembly:build_model"
ROOT = Path(__file__).resolve().parent.parent


def finishes_per_order(records: Iterable[Record]) -> list[tuple[str, dict[str, int]]]:
    """(variant, operation -> finishes) of each order, from its start to the next one's."""
    orders: list[tuple[str, dict[str, int]]] = []
    for record in records:
        if record.kind is RecordKind.EVENT and isinstance(record.data, OrderStarted):
            orders.append((record.data.variant, {}))
        elif isinstance(record.data, OperationRecord) and record.data.after == "finished":
            assert orders, f"{record.key} finished before any order started"
            counts = orders[-1][1]
            counts[record.key] = counts.get(record.key, 0) + 1
    return orders


def assert_each_operation_once_per_order(model: Model, records: list[Record], count: int) -> None:
    orders = finishes_per_order(records)
    assert len(orders) == count
    for variant, counts in orders:
        assert counts == dict.fromkeys(model.variant_by_name[variant].requested(model.operations), 1), variant


def _run(model: Model, plan: ProductionPlan, seed: int, failure: dict[str, float] | None = None) -> list[Record]:
    sink = ListSink()
    summary = run_in_process(model, seed=seed, failure=failure, recording=sink, production=plan,
                             time_limit=7200.0)
    assert summary.finished, summary.reason
    assert summary.throughput is not None and summary.throughput.orders == len(plan.orders)
    return sink.records


def test_two_orders_in_process_run_each_operation_of_their_variant_once() -> None:
    model = load_model(REFERENCE)
    plan = ProductionPlan(mixed({"full": 1, "light": 1}, 2), "test")
    records = _run(model, plan, seed=1)
    assert_each_operation_once_per_order(model, records, 2)
    # The product is reset between them: every operation of the full order goes finished -> initial.
    resets = {r.key for r in records if isinstance(r.data, OperationRecord) and r.data.before == "finished"
              and r.data.after == "initial"}
    assert resets == set(model.variant_by_name["full"].requested(model.operations)) | \
        set(model.variant_by_name["light"].requested(model.operations))
    finished = [r.data for r in records if isinstance(r.data, OrderFinished)]
    assert [(f.order, f.variant) for f in finished] == [(1, "full"), (2, "light")]
    assert all(f.cycle_s > 0 and f.line.startswith(f"order {f.order} ") for f in finished)


def test_a_run_without_orders_runs_every_operation_once_and_starts_no_order() -> None:
    model = load_model(REFERENCE)
    sink = ListSink()
    summary = run_in_process(model, seed=1, recording=sink)
    assert summary.finished and summary.throughput is None and not summary.orders
    assert not [r for r in sink.records if isinstance(r.data, OrderStarted | OrderFinished)]


# --- each operation done once, over restarts --------------------------------------------------------

def _op(key: str, before: str, after: str) -> Record:
    return Record(0.0, RecordKind.OPERATION, key,
                  OperationRecord(before=OperationState(before), after=OperationState(after)))


def test_an_order_reset_restored_by_the_next_controller_lets_the_operation_finish_again() -> None:
    done = DoneOnce([])
    count_finishes([_op("A", "executing", "finished")], done)  # killed as the order ended: its reset unrecorded
    restored = RestoreRecord(values={"op.A": "initial"})
    count_finishes([Record(0.0, RecordKind.RESTORE, "load", restored), _op("A", "initial", "executing"),
                    _op("A", "executing", "finished")], done)
    assert done.finishes == {"A": 2} and done.resets == {"A": 1} and not done.redone()


def test_an_order_reset_recorded_counts_once_beside_its_restore_record() -> None:
    done = DoneOnce([])
    reset = Record(0.0, RecordKind.RESTORE, "load", RestoreRecord(values={"op.A": "initial"}))
    count_finishes([_op("A", "executing", "finished"), reset, _op("A", "finished", "initial"),
                    _op("A", "initial", "finished"), _op("A", "finished", "executing"),
                    _op("A", "executing", "finished")], done)
    assert done.resets == {"A": 1} and done.redone() == {"A": 3}


def test_a_status_of_an_older_controller_decodes_without_production() -> None:
    status = decode(encode(StatusMessage(station="s", controller="c", time=0.0, uptime=0.0)), StatusMessage)
    assert status.production is None
    info = ProductionInfo(queued=2, done=1)
    again = decode(encode(StatusMessage(station="s", controller="c", time=0.0, uptime=0.0, production=info)),
                   StatusMessage)
    assert again.production == info


# --- over real processes ---------------------------------------------------------------------------

@pytest.fixture
def reference_station(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The reference station recording into a directory of this test's own. The suite's recordings go to one
    directory per test process (conftest.py, $STATEHUB_RECORDING_DIR, which beats hubs.toml's `dir`): read from
    there, the runs of the tests before were counted as this one's (every finish twice, issue 22)."""
    monkeypatch.setenv(RECORDING_DIR_ENV, str(tmp_path / "runs"))
    config = tmp_path / "hubs.toml"
    text = (ROOT / "hubs.toml").read_text().replace('dir = "var/runs"', f'dir = "{tmp_path / "runs"}"', 1)
    assert str(tmp_path) in text
    config.write_text(text)
    return config


async def _client(config: Path, lines: list[str]) -> list[str]:
    """An MES of its own: once the station runs, add two orders and cancel the last (queued) one."""
    station, model = load_station(config)
    while not (port := next((m.group(1) for line in lines if (m := re.search(r"127\.0\.0\.1:(\d+)", line))), None)):
        await asyncio.sleep(0.1)
    while not any("started" in line for line in lines):
        await asyncio.sleep(0.2)
    seen = []

    def session() -> ZenohBus:
        return ZenohBus(watcher_zenoh_config(station, model, int(port), None))

    added = await _add_once(session, station.keys)
    seen.append(f"added {[o.id for o in added.orders]}")
    async with session() as bus:
        cancelled = await ask_orders(bus, station.keys, OrdersRequest(action=OrdersAction.CANCEL,
                                                                      order=added.orders[-1].id), timeout=10.0)
    assert cancelled.accepted and cancelled.orders[0].state is OrderState.CANCELLED, cancelled.reason
    seen.append(f"cancelled {added.orders[-1].id}")
    return seen


MES = "test MES"


async def _add_once(session: Callable[[], ZenohBus], keys: Keys) -> OrdersReply:
    """Two light orders, added once although the controller may be down (`--chaos` kills it) when asked: an
    unanswered request may still have been applied, so the orders are looked for before asking again. Each
    attempt on a session of its own, as an MES reconnects: once, under the suite's load, no request of a first
    session reached the controller in two minutes."""
    for _attempt in range(12):
        async with session() as bus:
            added = await ask_orders(bus, keys, OrdersRequest(action=OrdersAction.ADD, variant="light", count=2,
                                                              origin=MES), timeout=10.0)
            if added.accepted:
                return added
            listed = await ask_orders(bus, keys, OrdersRequest(action=OrdersAction.LIST, include_finished=True),
                                      timeout=10.0)
        mine = [o for o in listed.orders if o.origin == MES]
        if mine:
            return OrdersReply(accepted=True, orders=mine)
    raise AssertionError(f"the orders were never added: {added.reason}")


async def _up_with_client(config: Path, **options: Any) -> tuple[int, str, list[str]]:
    lines: list[str] = []
    plan = ProductionPlan(mixed({"full": 1, "light": 1}, 5), "test")
    client = asyncio.create_task(_client(config, lines))
    code = await run_station(Options(config=str(config), run_dir=config.parent / "up", time_limit=600.0, speed=4.0,
                                     orders=5, mix="full:1,light:1", production=plan, **options),
                             say=lines.append)
    return code, "\n".join(lines), await client


def _records(config: Path) -> list[Record]:
    station, _ = load_station(config)
    records: list[Record] = []
    for path in run_recordings(str(config), station.station.name, 0.0):
        with open_run(path) as run:
            records += run.events(kinds={RecordKind.OPERATION, RecordKind.EVENT})
    return records


@pytest.mark.slow
@pytest.mark.timeout(900)
async def test_up_runs_five_orders_and_one_a_client_adds_each_operation_once_per_engine(
        reference_station: Path) -> None:
    code, output, client = await _up_with_client(reference_station)
    assert code == 0, output
    assert client == ["added [6, 7]", "cancelled 7"], output
    assert "finished: 6/6 orders" in output and "throughput: 6 engines in" in output, output
    # At speed 4 the controller's bound is at the devices' speed too: never above the cycle it bounds.
    cycle_line = next(line for line in output.splitlines() if line.startswith("cycle "))
    cycle_s, bound_s = (float(cycle_line.split(part, 1)[1].split(" s", 1)[0]) for part in ("cycle ", "bound "))
    assert 0 < bound_s <= cycle_s, cycle_line
    station, model = load_station(reference_station)
    assert_each_operation_once_per_order(model, _records(reference_station), 6)
    done = check_done_once(run_recordings(str(reference_station), station.station.name, 0.0))
    assert not done.failed() and done.work is not None and not done.work.missed(), done.text()


def expected_finishes(model: Model, variants: Iterable[str]) -> dict[str, int]:
    expected: dict[str, int] = {}
    for variant in variants:
        for op in model.variant_by_name[variant].requested(model.operations):
            expected[op] = expected.get(op, 0) + 1
    return expected


@pytest.mark.slow
@pytest.mark.timeout(900)
async def test_up_with_chaos_3_runs_every_order_with_each_operation_done_once(reference_station: Path) -> None:
    code, output, _client_said = await _up_with_client(reference_station, chaos=3, seed=1)
    assert code == 0, output
    assert "finished: 6/6 orders" in output, output
    station, model = load_station(reference_station)
    done = check_done_once(run_recordings(str(reference_station), station.station.name, 0.0))
    assert not done.failed(), done.text()
    assert done.finishes == expected_finishes(model, ["full", "light"] * 3), done.text()
    assert done.work is not None and len(done.work.asked) == 6, done.text()  # each of the 6 orders' work counted


def test_planned_orders_are_queued_once_in_one_commit(tmp_path: Path) -> None:
    from controller.production.book import OrderBook
    from controller.production.flow import OrderFlow
    from controller.state import StateStore

    model = load_model(REFERENCE)
    store = StateStore(tmp_path / "c.sqlite")
    flow = OrderFlow(OrderBook(store, model))
    plan = ProductionPlan((PlannedOrder("full"), PlannedOrder("light", "E-7")), "test")
    assert flow.queue(plan) == 2
    assert flow.queue(plan) == 0  # a restarted controller finds its plan queued
    assert [(o.variant, o.product_id) for o in flow.book.orders()] == [("full", "engine_assembly-00001"),
                                                                       ("light", "E-7")]
