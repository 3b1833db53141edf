"""Asking the controller about orders: what `hubctl orders`, the console or a test's MES sends."""

from __future__ import annotations

from common.bus.protocol import Bus
from common.wire.keys import Keys
from common.wire.orders import ORDERS_KEY, OrdersReply, OrdersRequest
from controller.ctl_query import ask_controller

ASK_TIMEOUT_S = 3.0


def refused(reason: str) -> OrdersReply:
    return OrdersReply(accepted=False, reason=reason)


async def ask_orders(bus: Bus, keys: Keys, request: OrdersRequest, timeout: float = ASK_TIMEOUT_S) -> OrdersReply:
    """The controller's answer; a controller that does not answer, or answers with an error, is a refusal
    saying so (in `tls` mode a certificate that may not ask gets no answer at all)."""
    key = keys.ctl(ORDERS_KEY)
    return await ask_controller(bus, key, request, OrdersReply, timeout=timeout, refuse=refused,
                                unanswered=f"no answer on {key} within {timeout:.0f} s: is the "
                                           f"controller running (and may this certificate ask)?")
