"""Handing products from station to station: the line controller's rounds (DESIGN.md §14).

Each round, for every station:

1. the orders of the products it has or is to get are listed (`{station}/ctl/orders`, list filtered by
   product id, in any state however old: a station that finished many other orders since, during a long
   outage, still reports these): a visit whose order the station reports done is marked done with the
   product's state the station archived, which makes the product's next visit ready and what it carries;
2. a ready visit's product is looked for in that list first, and only if the station has no order for it
   is one added, with the product's id. The station's order book refuses a second order for a product id,
   and the lookup comes first, so a handover repeated after any restart (of this controller before it
   committed, of the station's controller, of a router that lost the reply) finds the order there and adds
   nothing: nothing is lost (the visit stays pending or added until the station says otherwise) and
   nothing is done twice. The order added carries the product's state as the previous station archived
   it (`Order.carried`): the next station keeps it with the order.

A station that does not answer is unreachable: its handovers wait, the others go on.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Protocol

from common.wire.orders import Order, OrdersAction, OrdersReply, OrdersRequest, OrderState

from .store import LineStore, Visit, VisitState

log = logging.getLogger("statehub.line")
ORIGIN = "line controller"


class StationLink(Protocol):
    async def ask(self, station: str, request: OrdersRequest) -> OrdersReply | None:
        """The station controller's reply; None when it does not answer (unreachable)."""
        ...


@dataclass
class RoundResult:
    added: list[Visit] = field(default_factory=list)
    done: list[Visit] = field(default_factory=list)
    unreachable: set[str] = field(default_factory=set)


class Handover:
    def __init__(self, store: LineStore, link: StationLink, stations: Mapping[str, str] | None = None) -> None:
        self.store = store
        self.link = link
        self.unreachable: set[str] = set()
        self.stations = stations or {}  # line name -> how the log names it

    async def round(self) -> RoundResult:
        result = RoundResult()
        added = self.store.visits(VisitState.ADDED)
        ready = self.store.ready()
        stations = sorted({v.station for v in (*added, *ready)})
        for station in stations:
            products = sorted({v.product_id for v in (*added, *ready) if v.station == station})
            listing = await self.link.ask(station, OrdersRequest(action=OrdersAction.LIST, product_ids=products,
                                                                 origin=ORIGIN))
            if listing is None or not listing.accepted:
                result.unreachable.add(station)
                continue
            orders = {order.product_id: order for order in listing.orders}
            for visit in (v for v in added if v.station == station):
                order = orders.get(visit.product_id)
                if order is not None and order.state is OrderState.DONE:
                    self.store.mark_done(visit, order.started_at, order.finished_at, order.archive)
                    result.done.append(visit)
                    log.info("%s left %s (order %d)", visit.product_id, station, order.id)
                elif order is not None and order.state is OrderState.CANCELLED:
                    log.warning("%s: its order %d at %s was cancelled there: the product waits", visit.product_id,
                                order.id, station)
            for visit in (v for v in ready if v.station == station):
                if await self._hand_over(visit, orders.get(visit.product_id), result):
                    result.added.append(visit)
        for station in sorted(result.unreachable - self.unreachable):
            log.warning("station %s unreachable: its handovers wait", station)
        for station in sorted(self.unreachable - result.unreachable):
            log.info("station %s reachable again", station)
        self.unreachable = result.unreachable
        return result

    async def _hand_over(self, visit: Visit, present: Order | None, result: RoundResult) -> bool:
        if present is not None:  # added before, its commit here lost (or its reply)
            self.store.mark_added(visit, present.id, visit.carried)
            log.info("%s: order %d at %s found there (a handover repeated)", visit.product_id, present.id,
                     visit.station)
            return True
        request = OrdersRequest(action=OrdersAction.ADD, variant=visit.variant, product_id=visit.product_id,
                                carried=dict(visit.carried), origin=ORIGIN)
        reply = await self.link.ask(visit.station, request)
        if reply is None:
            result.unreachable.add(visit.station)
            return False
        if not reply.accepted or not reply.orders:
            log.warning("%s: %s refused its order: %s", visit.product_id, visit.station, reply.reason)
            return False
        self.store.mark_added(visit, reply.orders[0].id, visit.carried)
        log.info("%s handed to %s (order %d)", visit.product_id, visit.station, reply.orders[0].id)
        return True
