"""A long run stays bounded (issue 22 item 5): what the controller keeps per order does not grow with the
number of orders. Counted in structures, not bytes: the RSS figure is tests/bench/bench_production.py's."""

from __future__ import annotations

from typing import Any

import pytest

from common.config.production import ProductionPlan, mixed
from common.stations import load_model
from common.wire.ctl import RECENT_ORDERS, OrderFinished
from controller.cycle import CycleRecord
from controller.events import EventLog
from controller.loop import ControlLoop
from controller.production import flow as flow_module
from deploy.local import inprocess

REFERENCE = "common.stations.engine_assembly:build_model"
EVENTS_HELD = 50


def test_spans_let_go_keep_their_busy_time_and_the_last_span() -> None:
    cycle = CycleRecord(["r"])
    cycle.spans["r"] = [[0.0, 1.0], [2.0, 4.0], [5.0, 5.5]]
    before = cycle.report(10.0).idle[0].idle
    cycle.forget_before(4.5)
    assert cycle.spans["r"] == [[5.0, 5.5]] and cycle.report(10.0).idle[0].idle == before
    cycle.forget_before(100.0)
    assert cycle.spans["r"] == [[5.0, 5.5]]  # the last span may still grow


def test_what_the_loop_keeps_per_order_does_not_grow_with_the_orders(monkeypatch: pytest.MonkeyPatch) -> None:
    """7 orders in process: once the windows are full (the recent orders the status carries, the figures' set
    to 2 here), the spans held, the finished orders' figures and the recent orders are no more after each
    order than after the 5th."""
    monkeypatch.setattr(flow_module, "RECENT_FIGURES", 2)
    sizes: list[int] = []
    tick = ControlLoop.tick

    def counting_tick(loop: ControlLoop, *args: Any, **kwargs: Any) -> object:
        ticked = tick(loop, *args, **kwargs)
        if any(type(event).__name__ == "OrderFinished" for event in ticked.orders):
            assert loop.orders is not None
            sizes.append(sum(len(spans) for spans in loop.cycle.spans.values()) + len(loop.orders.finished)
                         + len(loop.orders.recent))
        return ticked

    monkeypatch.setattr(ControlLoop, "tick", counting_tick)
    model = load_model(REFERENCE)
    summary = inprocess.run_in_process(model, seed=1, production=ProductionPlan(mixed({"full": 1}, 7), "test"),
                                       time_limit=7200.0)
    assert summary.finished and summary.throughput is not None and summary.throughput.orders == 7
    assert len(sizes) == 7 and len(summary.orders) == 2
    assert max(sizes[RECENT_ORDERS:]) <= sizes[RECENT_ORDERS - 1], sizes


def test_over_orders_the_caches_the_event_log_and_the_order_books_tables_stop_growing(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """10 orders in process: after the 5th, the planner's memories (plans and searches), the goals without a
    plan, the event log held, the finished orders' figures and the order book's state tables are no larger
    than then. The order book keeps a row per order (that is the data); the event log holds at most its bound
    although more events were emitted; the recording is a file per controller start, rotated
    (controller/recording)."""
    sizes: list[dict[str, int]] = []
    tick = ControlLoop.tick
    seen: list[ControlLoop] = []

    def counting_tick(loop: ControlLoop, *args: Any, **kwargs: Any) -> object:
        ticked = tick(loop, *args, **kwargs)
        if any(isinstance(event, OrderFinished) for event in ticked.orders):
            core, flow = loop.core, loop.orders
            assert flow is not None
            db = flow.book.store.db
            sizes.append({
                "plans remembered": len(core.planner.memory),
                "searches remembered": len(core.planner.searches),
                "goals without a plan": len(core.errors),
                "events held": len(list(core.events.log)),
                "figures kept": len(flow.finished),
                "state variables": db.execute("SELECT COUNT(*) FROM variables").fetchone()[0],
                "state meta": db.execute("SELECT COUNT(*) FROM meta").fetchone()[0],
                "orders": db.execute("SELECT COUNT(*) FROM orders").fetchone()[0],
            })
            seen[:] = [loop]
        return ticked

    monkeypatch.setattr(flow_module, "RECENT_FIGURES", 2)
    monkeypatch.setattr(EventLog.__init__, "__defaults__", (EVENTS_HELD,))  # full within the run (30 an order)
    monkeypatch.setattr(ControlLoop, "tick", counting_tick)
    model = load_model(REFERENCE)
    summary = inprocess.run_in_process(model, seed=1, production=ProductionPlan(mixed({"full": 1, "light": 1}, 10),
                                                                               "test"), time_limit=7200.0)
    assert summary.finished and len(sizes) == 10
    settled = sizes[4]
    for later in sizes[5:]:
        grown = {name: (settled[name], count) for name, count in later.items() if count > settled[name]}
        assert not grown, grown
    assert sizes[-1]["orders"] == 10 and sizes[-1]["searches remembered"] > 0
    log = seen[0].core.events.log
    assert sizes[-1]["events held"] == EVENTS_HELD < log.total, (sizes[-1]["events held"], log.total)
