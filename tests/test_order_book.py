"""The order book: the queue's transitions, the product's state with them, and what survives a crash."""

from __future__ import annotations

import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from common.model import Model, OperationState, Value
from common.stations.engine_assembly import build_model
from common.wire.orders import OrderState
from controller.production.book import REQUESTED_META, OrderBook, OrderError
from controller.state import StateStore

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def model() -> Model:
    return build_model()


@pytest.fixture
def book(tmp_path: Path, model: Model) -> Iterator[OrderBook]:
    store = StateStore(tmp_path / "controller.sqlite")
    ticks = iter(range(1000, 10**6))
    yield OrderBook(store, model, clock=lambda: float(next(ticks)))
    store.close()


def _all_finished(book: OrderBook, values: dict[str, Value]) -> dict[str, Value]:
    current = book.current()
    assert current is not None
    return {**values, **{f"op.{name}": OperationState.FINISHED.value for name in book.requested(current)}}


def test_orders_queue_start_in_order_and_only_when_the_station_is_free(book: OrderBook) -> None:
    first, second = book.add("full", count=2, origin="test")
    light = book.add("light", product_id="E-7", parameters={"engine.count_bolts_e": 22})[0]
    assert [o.id for o in book.orders()] == [1, 2, 3] and first.product_id == "engine_assembly-00001"
    assert light.product_id == "E-7" and light.parameters == {"engine.count_bolts_e": 22}
    started = book.next()
    assert started is not None and started.order.id == first.id and started.order.state is OrderState.RUNNING
    assert book.next() is None  # one product on the station at a time
    assert book.current() == started.order
    assert started.operations[-1] == "MirLeave" and len(started.operations) == 45
    assert started.values["engine.count_bolts_e"] == 24 and started.values["op.AgvArrive"] == "initial"
    assert book.store.meta(REQUESTED_META) == list(started.operations)
    assert second.state is OrderState.QUEUED


def test_a_variant_requests_its_operations_and_its_parameters_start_the_product(book: OrderBook) -> None:
    book.add("light", parameters={"engine.count_bolts_e": 22})
    started = book.next()
    assert started is not None
    assert "TightenBolt21" not in started.operations and "MountOilPipes" not in started.operations
    assert started.values["engine.count_bolts_e"] == 22 and started.values["engine.count_pipes_e"] == 0
    stored, _ = book.store.load(book.model)
    assert stored["engine.count_bolts_e"] == 22  # committed with the order's start


def test_finish_archives_the_product_once_and_resets_it(book: OrderBook, model: Model) -> None:
    book.add("full")
    started = book.next()
    assert started is not None and not book.complete(started.order, started.values)
    state = _all_finished(book, {**model.initial_state(), "engine.bolt1_e": "tightened", "ur.pos_m": "home"})
    assert book.complete(started.order, state)
    finished = book.finish(started.order, state)
    assert finished.order.state is OrderState.DONE and finished.order.finished_at is not None
    assert finished.archive["engine.bolt1_e"] == "tightened" and "ur.pos_m" not in finished.archive
    assert finished.reset["engine.bolt1_e"] == "absent" and finished.reset["op.MirLeave"] == "initial"
    assert book.store.meta(REQUESTED_META) == []
    again = book.finish(started.order, {**state, "engine.bolt1_e": "placed"})
    assert again.archive == finished.archive == book.archive(started.order.id)  # written once
    assert book.current() is None


def test_what_the_book_refuses_it_says_why(book: OrderBook) -> None:
    with pytest.raises(OrderError, match=r"no variant 'medium' .*its variants: full, light"):
        book.add("medium")
    with pytest.raises(OrderError, match=r"variant light has no parameter engine\.frame_e"):
        book.add("light", parameters={"engine.frame_e": "placed"})
    with pytest.raises(OrderError, match=r"engine.count_bolts_e = 25 is outside"):
        book.add("light", parameters={"engine.count_bolts_e": 25})
    with pytest.raises(OrderError, match="count 0"):
        book.add("full", count=0)
    book.add("full", product_id="E-1")
    with pytest.raises(OrderError, match="product 'E-1' already has an order"):
        book.add("light", product_id="E-1")
    book.add("full")
    assert book.next() is not None
    with pytest.raises(OrderError, match="order 1 is running: its product is on the station"):
        book.cancel(1)
    cancelled = book.cancel(2)
    assert cancelled.state is OrderState.CANCELLED
    with pytest.raises(OrderError, match="order 2 is already cancelled"):
        book.cancel(2)
    with pytest.raises(OrderError, match="no order 9"):
        book.cancel(9)
    assert [o.id for o in book.orders()] == [1] and [o.id for o in book.orders(include_finished=True)] == [2, 1]


def test_a_restarted_controller_finds_the_running_order_and_its_product(tmp_path: Path, model: Model) -> None:
    store = StateStore(tmp_path / "controller.sqlite")
    book = OrderBook(store, model)
    book.add("light", count=2)
    started = book.next()
    assert started is not None
    store.save({"engine.bolt3_e": "tightened"})  # the controller's own progress
    store.close()
    store = StateStore(tmp_path / "controller.sqlite")
    book = OrderBook(store, model)
    assert book.current() == started.order and book.next() is None
    values, _ = store.load(model)
    assert values["engine.bolt3_e"] == "tightened" and values["engine.count_pipes_e"] == 0  # nothing redone
    assert store.meta(REQUESTED_META) == list(started.operations)
    store.close()


WRITER = """
import sys
from common.stations.engine_assembly import build_model
from controller.production.book import OrderBook
from controller.state import StateStore
model = build_model()
book = OrderBook(StateStore(sys.argv[1]), model)
state = model.initial_state()
for n in range(1_000_000):
    book.add("light" if n % 2 else "full")
    started = book.next()
    state.update(started.values)
    state.update({f"op.{name}": "finished" for name in started.operations})
    book.finish(started.order, state)
    print(n, flush=True)
    if n >= 3:
        sys.stdin.readline()  # hold here: the parent kills us right after this finish returned
"""


def test_every_transition_that_returned_survives_kill_9(tmp_path: Path, model: Model) -> None:
    db = tmp_path / "controller.sqlite"
    writer = subprocess.Popen([sys.executable, "-c", WRITER, str(db)], cwd=ROOT, stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert writer.stdout is not None
        lines = [writer.stdout.readline() for _ in range(4)]
        assert lines[-1].strip() == "3", lines
        writer.send_signal(signal.SIGKILL)
        writer.wait(timeout=10)
    finally:
        if writer.poll() is None:
            writer.kill()
    store = StateStore(db)
    book = OrderBook(store, model)
    finished = book.orders(include_finished=True)
    assert [(o.id, o.variant, o.state) for o in finished] == [
        (1, "full", OrderState.DONE), (2, "light", OrderState.DONE), (3, "full", OrderState.DONE),
        (4, "light", OrderState.DONE)]
    assert book.archive(4)["engine.count_bolts_e"] == 20 and book.archive(3)["engine.count_bolts_e"] == 24
    values, _ = store.load(model)
    assert values["engine.count_bolts_e"] == 24 and values["op.AgvLeave"] == "initial"  # reset with the finish
    store.close()
