"""Asking the controller about orders: what `hubctl orders`, the console or a test's MES sends."""

from __future__ import annotations

from common.bus.protocol import Bus
from common.wire.keys import Keys
from common.wire.messages import MessageError, decode, encode
from common.wire.orders import ORDERS_KEY, OrdersReply, OrdersRequest

ASK_TIMEOUT_S = 3.0


async def ask_orders(bus: Bus, keys: Keys, request: OrdersRequest, timeout: float = ASK_TIMEOUT_S) -> OrdersReply:
    """The controller's answer; a controller that does not answer, or answers with an error, is a refusal
    saying so (in `tls` mode a certificate that may not ask gets no answer at all)."""
    replies = await bus.get(keys.ctl(ORDERS_KEY), payload=encode(request), timeout=timeout)
    for reply in replies:
        if not reply.ok:
            failure = reply.payload.decode(errors="replace")
            return OrdersReply(accepted=False, reason=f"the controller failed: {failure}")
        try:
            return decode(reply.payload, OrdersReply)
        except MessageError as exc:
            return OrdersReply(accepted=False, reason=f"unreadable reply: {exc}")
    return OrdersReply(accepted=False, reason=f"no answer on {keys.ctl(ORDERS_KEY)} within {timeout:.0f} s: is the "
                                              f"controller running (and may this certificate ask)?")
