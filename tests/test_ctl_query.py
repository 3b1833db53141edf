"""`ask_controller` over an in-memory bus: the answer, and each way of not getting one as a refusal of the
asker's own reply type saying which (what `hubctl orders` and the console show)."""

from __future__ import annotations

from collections.abc import AsyncIterator

import pytest

from common.bus.memory_bus import MemoryBus, MemoryHub
from common.bus.protocol import QueryHandler, Request
from common.wire.messages import decode, encode
from common.wire.orders import OrdersAction, OrdersReply, OrdersRequest
from controller.ctl_query import ask_controller

KEY = "station/ctl/orders"
REQUEST = OrdersRequest(action=OrdersAction.LIST)


def refused(reason: str) -> OrdersReply:
    return OrdersReply(accepted=False, reason=reason)


@pytest.fixture
async def buses() -> AsyncIterator[tuple[MemoryBus, MemoryBus]]:
    hub = MemoryHub()
    async with MemoryBus(hub) as controller, MemoryBus(hub) as asker:
        yield controller, asker


async def ask(asker: MemoryBus) -> OrdersReply:
    return await ask_controller(asker, KEY, REQUEST, OrdersReply, timeout=1.0, refuse=refused,
                                unanswered="nobody answered")


async def answering(controller: MemoryBus, handler: QueryHandler, asker: MemoryBus) -> OrdersReply:
    queryable = controller.declare_queryable(KEY, handler)
    try:
        return await ask(asker)
    finally:
        queryable.undeclare()


async def test_the_controllers_answer_is_decoded_as_the_askers_type(buses: tuple[MemoryBus, MemoryBus]) -> None:
    asked: list[OrdersRequest] = []

    async def answer(request: Request) -> bytes:
        asked.append(decode(request.payload or b"", OrdersRequest))
        return encode(OrdersReply(accepted=True, reason="listed"))

    reply = await answering(buses[0], answer, buses[1])
    assert reply == OrdersReply(accepted=True, reason="listed")
    assert asked == [REQUEST]


async def test_a_failing_controller_is_a_refusal_with_its_error(buses: tuple[MemoryBus, MemoryBus]) -> None:
    async def fail(_request: Request) -> bytes:
        raise RuntimeError("the order book is closed")

    reply = await answering(buses[0], fail, buses[1])
    assert not reply.accepted
    assert reply.reason.startswith("the controller failed: ")
    assert "the order book is closed" in reply.reason


async def test_an_undecodable_answer_is_a_refusal(buses: tuple[MemoryBus, MemoryBus]) -> None:
    async def garble(_request: Request) -> bytes:
        return b"\xc1 not msgpack"

    reply = await answering(buses[0], garble, buses[1])
    assert not reply.accepted
    assert reply.reason.startswith("unreadable reply from the controller: OrdersReply")


async def test_no_answer_is_a_refusal_with_the_askers_reason(buses: tuple[MemoryBus, MemoryBus]) -> None:
    reply = await ask(buses[1])
    assert reply == OrdersReply(accepted=False, reason="nobody answered")
