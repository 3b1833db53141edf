"""Long runs in process (issue 22): 200 orders per seed, with and without a failing nutrunner, finish with each
operation of each order's variant finished once and no physical work done twice in an order. The checks are
done_once's (deploy/local/done_once.py) counted as the run goes (`DoneOnceSink`), so a run keeps no records.

The suite runs one seed of each (each run is 5 to 7 minutes of a core on a loaded 2-core machine: three seeds
were 31 of the suite's 76 worker-minutes); tests/bench/bench_production.py runs the issue's 20 seeds of each
(see the README's production figures)."""

from __future__ import annotations

from typing import Any

import pytest

from common.config.production import ProductionPlan, mixed
from common.model import Model, OperationState
from common.stations import load_model
from common.wire.ctl import OrderStarted
from controller.recording.schema import OperationRecord, RecordKind
from deploy.local.done_once import DoneOnceSink
from deploy.local.inprocess import run_in_process

REFERENCE = "common.stations.engine_assembly:build_model"
LONG_ORDERS = 200
SUITE_SEEDS = (1,)
FAIL_RATE = 0.2  # `hubctl up --in-process --fail-rate 0.2`: the nutrunner fails a fifth of its tightenings


class OrderSink(DoneOnceSink):
    """done_once's counts, and each order's variant with the finishes of each operation while it ran."""

    def __init__(self, model: Model) -> None:
        super().__init__(model)
        self.orders: list[tuple[str, dict[str, int]]] = []

    def put(self, t: float, kind: RecordKind, key: str, data: Any) -> None:
        super().put(t, kind, key, data)
        if isinstance(data, OrderStarted):
            self.orders.append((data.variant, {}))
        elif isinstance(data, OperationRecord) and data.after == OperationState.FINISHED:
            assert self.orders, f"{key} finished before any order started"
            counts = self.orders[-1][1]
            counts[key] = counts.get(key, 0) + 1


def run_orders(model: Model, orders: int, seed: int, fail_rate: float = 0.0) -> OrderSink:
    sink = OrderSink(model)
    plan = ProductionPlan(mixed({"full": 1, "light": 1}, orders), "test")
    summary = run_in_process(model, seed=seed, failure={"nr": fail_rate} if fail_rate else None, recording=sink,
                             production=plan, time_limit=orders * 600.0)
    assert summary.finished, summary.reason
    assert summary.throughput is not None and summary.throughput.orders == orders
    return sink


def assert_each_operation_once_per_order(model: Model, sink: OrderSink, orders: int) -> None:
    assert len(sink.orders) == orders
    for number, (variant, counts) in enumerate(sink.orders, 1):
        assert counts == dict.fromkeys(model.variant_by_name[variant].requested(model.operations), 1), \
            f"order {number} ({variant})"
    done = sink.done
    assert not done.failed(), done.text()
    assert done.work is not None and not done.work.missed(), done.text()
    assert set(done.work.asked) == set(range(1, orders + 1))


def test_the_counting_sink_sees_an_operation_finished_twice_in_an_order() -> None:
    model = load_model(REFERENCE)
    sink = OrderSink(model)
    started = OrderStarted(order=1, product_id="p1", variant="full", operations=45)
    sink.put(0.0, RecordKind.EVENT, "order_started", started)
    for _ in range(2):
        sink.put(5.0, RecordKind.OPERATION, "TightenBolt7",
                 OperationRecord(before=OperationState.EXECUTING, after=OperationState.FINISHED))
        sink.put(5.0, RecordKind.OPERATION, "TightenBolt7",
                 OperationRecord(before=OperationState.FINISHED, after=OperationState.EXECUTING))
    assert sink.done.redone() == {"TightenBolt7": 2} and sink.done.failed()
    assert sink.orders == [("full", {"TightenBolt7": 2})]


def test_four_orders_counted_as_they_run_each_operation_once() -> None:
    model = load_model(REFERENCE)
    assert_each_operation_once_per_order(model, run_orders(model, 4, seed=1), 4)


@pytest.mark.slow
@pytest.mark.timeout(3600)
@pytest.mark.parametrize("fail_rate", [0.0, FAIL_RATE], ids=["nominal", "fail-rate-0.2"])
@pytest.mark.parametrize("seed", SUITE_SEEDS)
def test_two_hundred_orders_in_process_each_operation_once_per_order(seed: int, fail_rate: float) -> None:
    model = load_model(REFERENCE)
    assert_each_operation_once_per_order(model, run_orders(model, LONG_ORDERS, seed, fail_rate), LONG_ORDERS)
