"""The order book as the control loop sees it: which order runs, when it is complete, and its throughput.

The control loop (controller/loop.py) asks it after each tick whether the running order is complete
and whether the next may start; the book commits each transition (controller/production/book.py),
this keeps what the loop and the shells need between ticks: the running order (the book is asked
again only when an order starts or finishes, not at every tick), the core-clock time it started, and
the newest finished orders' throughput for the lines `hubctl up` prints and the status carries.

Nothing here grows with the number of orders (a shift runs thousands): the figures of the last
`RECENT_FIGURES` orders are kept, the run's figures are read from the book when asked (every order's
times are in its SQLite table, as the recording has every order's events).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from common.config.production import ProductionPlan
from common.wire.ctl import RECENT_ORDERS, OrderDone, ProductionInfo
from common.wire.orders import Order, OrderState

from .book import OrderBook
from .throughput import OrderThroughput, OrderWindow, RunThroughput, order_throughput, run_throughput

RECENT_FIGURES = 50  # finished orders whose throughput (busy and waiting times) is kept in memory


@dataclass(frozen=True)
class BusySpan:
    """A resource busy from `start` to `end` on the core's clock (controller/cycle.py's spans)."""

    lane: str
    start: float
    end: float


class OrderFlow:
    def __init__(self, book: OrderBook) -> None:
        self.book = book
        self.current: Order | None = book.current()  # a restarted controller goes on with the order it finds
        self.requested: tuple[str, ...] = () if self.current is None else book.requested(self.current)
        self.finished: deque[OrderThroughput] = deque(maxlen=RECENT_FIGURES)  # the newest, with their busy times
        self.recent: deque[OrderDone] = deque(maxlen=RECENT_ORDERS)
        self.done = book.count(OrderState.DONE)

    def queue(self, plan: ProductionPlan) -> int:
        """Queue `plan` once: only into a book that never had an order (a fresh start; a restarted controller
        finds the plan queued already). The orders queued."""
        if not self.book.empty():
            return 0
        return len(self.book.add_plan(plan))

    def started(self, order: Order, operations: tuple[str, ...]) -> None:
        self.current, self.requested = order, operations

    def finished_order(self, order: Order, end: float, spans: dict[str, list[list[float]]]) -> OrderThroughput:
        """The order just finished (`order` as the book returned it, with its times), its throughput from the
        resources' busy `spans`, which end at `end` on the core's clock."""
        cycle = (order.finished_at or 0.0) - (order.started_at or 0.0)
        window = OrderWindow(order.id, order.product_id, order.variant, end - cycle, end)
        busy = (BusySpan(resource, start, stop) for resource, intervals in spans.items()
                for start, stop in intervals if stop > window.start)
        figures = order_throughput(window, busy, list(spans))
        self.finished.append(figures)
        self.recent.append(OrderDone(order.id, order.product_id, order.variant, order.started_at or 0.0,
                                     order.finished_at or 0.0))
        self.done += 1
        self.current, self.requested = None, ()
        return figures

    def idle(self) -> bool:
        """No order runs and none waits: a station running orders is finished."""
        return self.current is None and self.book.queued() == 0

    def run_figures(self) -> RunThroughput:
        """Engines per hour and cycle times of the book's done orders, on its clock, over the span from the first
        one's start to the last one's end."""
        done = [OrderThroughput(o.id, o.product_id, o.variant, o.started_at or 0.0, o.finished_at or 0.0, {})
                for o in self.book.done_orders()]
        if not done:
            return run_throughput([], 0.0)
        return run_throughput(done, max(o.end for o in done) - min(o.start for o in done))

    def info(self) -> ProductionInfo:
        return ProductionInfo(current=self.current, queued=self.book.queued(), done=self.done,
                              recent=list(self.recent))
