"""The controller's order queryable: `{station}/ctl/orders` answers add, cancel and list.

An MES, `hubctl orders` or the console sends an `OrdersRequest` as a Zenoh query and gets one
`OrdersReply`. In `tls` mode only an operator's certificate may query the key
(common/config/acl.py). The service runs on the controller's event loop, the thread that owns
the order book's SQLite connection; `answered(request, reply)` is told each request and its
answer (the event log, the recording), `changed()` each change of the queue (the loop may start
the next order at once rather than at its next tick).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

from common.bus.protocol import Bus, Queryable, Request
from common.wire.keys import Keys
from common.wire.messages import MessageError, decode, encode
from common.wire.orders import ORDERS_KEY, OrdersAction, OrdersReply, OrdersRequest

from .book import OrderBook, OrderError

log = logging.getLogger("statehub.controller.orders")


def _ignore(_request: OrdersRequest, _reply: OrdersReply) -> None:
    return None


class OrdersService:
    def __init__(self, book: OrderBook, *, answered: Callable[[OrdersRequest, OrdersReply], None] = _ignore,
                 changed: Callable[[], None] = lambda: None) -> None:
        self.book = book
        self.answered = answered
        self.changed = changed

    def declare(self, bus: Bus, keys: Keys) -> Queryable:
        """Answer on `{station}/ctl/orders` until the returned queryable is undeclared (or the bus closes)."""
        return bus.declare_queryable(keys.ctl(ORDERS_KEY), self.answer)

    async def serve(self, bus: Bus, keys: Keys) -> None:
        """Answer until cancelled (a task of the controller's)."""
        queryable = self.declare(bus, keys)
        try:
            await asyncio.get_running_loop().create_future()
        finally:
            queryable.undeclare()

    async def answer(self, query: Request) -> bytes:
        if query.payload is None:
            return encode(OrdersReply(accepted=False, reason="empty request: expected an OrdersRequest"))
        try:
            request = decode(query.payload, OrdersRequest)
        except MessageError as exc:
            log.warning("unreadable orders request on %s: %s", query.key, exc)
            return encode(OrdersReply(accepted=False, reason=f"unreadable request: {exc}"))
        return encode(self.apply(request))

    def apply(self, request: OrdersRequest) -> OrdersReply:
        try:
            reply = self._decide(request)
        except OrderError as exc:
            reply = OrdersReply(accepted=False, reason=str(exc))
        if request.action is not OrdersAction.LIST:
            log.info("orders: %s (%s): %s", request.describe(), request.origin or "?",
                     "accepted" if reply.accepted else f"refused: {reply.reason}")
            if reply.accepted:
                self.changed()
        self.answered(request, reply)
        return reply

    def _decide(self, request: OrdersRequest) -> OrdersReply:
        if request.action is OrdersAction.ADD:
            added = self.book.add(request.variant, product_id=request.product_id, parameters=request.parameters,
                                  origin=request.origin, count=request.count, carried=request.carried)
            return OrdersReply(accepted=True, reason=f"{len(added)} queued; {self.book.queued()} in the queue",
                               orders=added)
        if request.action is OrdersAction.CANCEL:
            return OrdersReply(accepted=True, orders=[self.book.cancel(request.order)])
        if request.product_ids:
            return OrdersReply(accepted=True, orders=self.book.orders_of(request.product_ids))
        return OrdersReply(accepted=True, orders=self.book.orders(include_finished=request.include_finished))
