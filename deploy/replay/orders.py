"""A recorded run's orders, for its replay: the order book the recording's controller had, rebuilt.

The orders themselves are inputs (hubs.toml's plan, `--orders`, an MES adding and cancelling while the
station runs: none of it is recorded as such); when each started and finished is the controller's
decision. So the replay's book holds the orders the recording saw start, each available from the time it
started, and the replayed loop decides when to finish one and start the next; its `order_started` and
`order_finished` events are compared with the recorded ones. An order's parameters are read from the
values its start loaded (its variant's parameters, then its own). A recording that begins with an order
under way (a restarted controller's) finishes one it never saw start: that order was running.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

from common.model import Model, Value
from common.wire.ctl import OrderFinished, OrderStarted
from common.wire.orders import Order, OrderState, ParameterValue
from controller.production.book import OrderBook, OrderStart
from controller.production.flow import OrderFlow
from controller.recording.reader import Record
from controller.recording.schema import RecordKind, RestoreRecord
from controller.state import StateStore

ORDER_EVENTS = frozenset({"order_started", "order_finished"})  # the event log's keys of the order decisions
REPLAY_ORIGIN = "replay"


@dataclass(frozen=True)
class RecordedOrder:
    order: Order
    started_t: float | None  # on the recording's clock; None: it was under way when the recording began


def recorded_orders(model: Model, records: Iterable[Record]) -> list[RecordedOrder]:
    """The orders a recording saw start or finish, in that order (`records`: its events and restores)."""
    found: dict[int, RecordedOrder] = {}
    loaded: dict[str, Value] = {}  # the last values loaded: an order's start values come right before it
    for record in records:
        data = record.data
        if isinstance(data, RestoreRecord):
            loaded = data.values
        elif isinstance(data, OrderStarted) and data.order not in found:
            variant = model.variant_by_name[data.variant]
            parameters: dict[str, ParameterValue] = {
                path: value for path, value in loaded.items()
                if path in variant.parameters and value != variant.parameters[path]}
            found[data.order] = RecordedOrder(
                Order(id=data.order, product_id=data.product_id, variant=data.variant, parameters=parameters),
                record.t)
        elif isinstance(data, OrderFinished) and data.order not in found:
            found[data.order] = RecordedOrder(
                Order(id=data.order, product_id=data.product_id, variant=data.variant, state=OrderState.RUNNING,
                      started_at=0.0), None)
    return list(found.values())


class ReplayOrderBook(OrderBook):
    """An order book in memory whose queued orders each become available at the time the recording started
    it: the replayed loop may not start an order before the recorded controller could have."""

    def __init__(self, model: Model, clock: Callable[[], float], orders: Iterable[RecordedOrder]) -> None:
        super().__init__(StateStore(":memory:"), model, clock)
        self.available: dict[int, float] = {}
        for recorded in orders:
            self.put(recorded.order)
            if recorded.started_t is not None:
                self.available[recorded.order.id] = recorded.started_t

    def next(self) -> OrderStart | None:
        queued = [o for o in self.orders() if o.state is OrderState.QUEUED]
        if not queued or self.available.get(queued[0].id, 0.0) > self.clock():
            return None
        return super().next()


def replay_flow(model: Model, clock: Callable[[], float], records: Iterable[Record]) -> OrderFlow:
    """The order flow of a replay: the recording's orders in a book of their own."""
    return OrderFlow(ReplayOrderBook(model, clock, recorded_orders(model, records)))


RECORDS_READ = frozenset({RecordKind.EVENT, RecordKind.RESTORE})  # what `recorded_orders` reads
