"""Orders, and what an MES, `hubctl orders` or the console asks of the controller about them.

An order is a product id, a variant of the station model and parameter values overriding the
variant's; the controller's order book (controller/production/book.py) keeps them. On a line an order
also carries the product's state as the previous station archived it (`carried`, kept with the order, not
applied to the station's variables), and a done order its own archive (`archive`). The requests
travel as a Zenoh query on `{station}/ctl/orders` carrying an `OrdersRequest`; the controller
answers one `OrdersReply`: accepted, or refused with the reason, and the orders concerned.
"""

from __future__ import annotations

import enum

import msgspec

from common.wire.messages import Message

ParameterValue = bool | int | str
ORDERS_KEY = "orders"  # under {station}/ctl/


class OrderState(enum.StrEnum):
    """queued -> running -> done, or queued -> cancelled."""

    QUEUED = "queued"
    RUNNING = "running"  # its product is on the station
    DONE = "done"  # its product left; its estimated state is archived with it
    CANCELLED = "cancelled"


class Order(msgspec.Struct, frozen=True, kw_only=True):
    id: int  # the order book's, counting up from 1
    product_id: str
    variant: str
    parameters: dict[str, ParameterValue] = msgspec.field(default_factory=dict)
    state: OrderState = OrderState.QUEUED
    origin: str = ""  # who added it (user@host, "hubs.toml", an MES's name)
    queued_at: float = 0.0  # wall clock, seconds since the epoch
    started_at: float | None = None
    finished_at: float | None = None  # done or cancelled
    # The product's state as the previous station of a line archived it (its product variables' values at
    # its finish), handed over by the line controller; {} for a product that starts here.
    carried: dict[str, ParameterValue] = msgspec.field(default_factory=dict)
    # A done order: its product's state as this station archived it at the finish; {} before.
    archive: dict[str, ParameterValue] = msgspec.field(default_factory=dict)

    def describe(self) -> str:
        parameters = "".join(f" {k}={v}" for k, v in sorted(self.parameters.items()))
        return f"order {self.id} ({self.product_id}, {self.variant}{parameters}): {self.state}"


class OrdersAction(enum.StrEnum):
    ADD = "add"
    CANCEL = "cancel"
    LIST = "list"


class OrdersRequest(Message, kw_only=True):
    action: OrdersAction
    variant: str = ""  # add
    count: int = 1  # add: this many orders of the variant
    product_id: str = ""  # add (count 1): the product's id; default: generated from the order id
    parameters: dict[str, ParameterValue] = msgspec.field(default_factory=dict)  # add
    order: int = 0  # cancel: the order's id
    include_finished: bool = False  # list: done and cancelled orders too (the newest LIST_FINISHED)
    # list: only the orders of these products, in any state (however old); empty: no filter
    product_ids: list[str] = msgspec.field(default_factory=list)
    carried: dict[str, ParameterValue] = msgspec.field(default_factory=dict)  # add (count 1): Order.carried
    origin: str = ""  # who asks (user@host), for the controller's event log

    def describe(self) -> str:
        if self.action is OrdersAction.ADD:
            return f"add {self.count} x {self.variant}" + (f" ({self.product_id})" if self.product_id else "")
        if self.action is OrdersAction.CANCEL:
            return f"cancel order {self.order}"
        return f"list the orders of {len(self.product_ids)} products" if self.product_ids else "list orders"


class OrdersReply(Message, kw_only=True):
    accepted: bool
    reason: str = ""  # why it was refused, or what follows from accepting it
    orders: list[Order] = msgspec.field(default_factory=list)  # added, cancelled, or listed
