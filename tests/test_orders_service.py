"""`{station}/ctl/orders` over real Zenoh sessions on loopback: an MES with its own session adds, lists and
cancels orders against an `OrdersService` served on another session; in `tls` mode only an operator's
certificate gets an answer (the station's access control, as tests/test_security.py checks `ctl/request`)."""

from __future__ import annotations

import asyncio
import json
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

from common.bus.protocol import Request
from common.bus.station_net import station_zenoh_config
from common.bus.zenoh_bus import ZenohBus
from common.bus.zenoh_config import zenoh_config
from common.config.acl import access_control
from common.config.hubs_toml import StationConfig, load_station
from common.config.security import identity_of
from common.model import Model
from common.plumbing.lifecycle import free_port
from common.wire.keys import station_keys
from common.wire.messages import encode
from common.wire.orders import ORDERS_KEY, OrdersAction, OrdersReply, OrdersRequest, OrderState
from controller.production.book import OrderBook
from controller.production.client import ask_orders
from controller.production.service import OrdersService
from controller.state import StateStore
from deploy.certs import init_ca, issue_for_station

ROOT = Path(__file__).resolve().parent.parent
LINK_S = 10.0  # a loopback session links well within this, even on a loaded machine


@pytest.fixture
def service(tmp_path: Path) -> Iterator[OrdersService]:
    _, model = load_station(ROOT / "hubs.toml")
    store = StateStore(tmp_path / "controller.sqlite")
    yield OrdersService(OrderBook(store, model))
    store.close()


async def _ask_until_answered(bus: ZenohBus, station: str, request: OrdersRequest) -> OrdersReply:
    """The first request waits for the sessions to link (routes are gossiped after the link opens)."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + LINK_S
    while True:
        reply = await ask_orders(bus, station_keys(station), request, timeout=0.5)
        if reply.accepted or "no answer" not in reply.reason or loop.time() > deadline:
            return reply


async def test_a_client_with_its_own_session_adds_lists_and_cancels_orders(service: OrdersService) -> None:
    port = free_port()
    keys = station_keys("engine_assembly")
    changes: list[str] = []
    service.changed = lambda: changes.append("changed")
    async with ZenohBus(zenoh_config("peer", listen=[f"tcp/127.0.0.1:{port}"])) as controller_bus:
        service.declare(controller_bus, keys)
        async with ZenohBus(zenoh_config("peer", connect=[f"tcp/127.0.0.1:{port}"])) as mes:
            added = await _ask_until_answered(mes, "engine_assembly", OrdersRequest(
                action=OrdersAction.ADD, variant="full", count=2, origin="mes"))
            assert added.accepted, added.reason
            assert [o.id for o in added.orders] == [1, 2] and added.reason == "2 queued; 2 in the queue"
            light = await ask_orders(mes, keys, OrdersRequest(action=OrdersAction.ADD, variant="light",
                                                              product_id="E-9", origin="mes"))
            assert light.accepted and light.orders[0].product_id == "E-9"
            assert service.book.next() is not None  # the station takes order 1
            refused = await ask_orders(mes, keys, OrdersRequest(action=OrdersAction.CANCEL, order=1))
            assert not refused.accepted and "order 1 is running" in refused.reason
            cancelled = await ask_orders(mes, keys, OrdersRequest(action=OrdersAction.CANCEL, order=2))
            assert cancelled.accepted and cancelled.orders[0].state is OrderState.CANCELLED
            unknown = await ask_orders(mes, keys, OrdersRequest(action=OrdersAction.ADD, variant="heavy"))
            assert not unknown.accepted and "no variant 'heavy'" in unknown.reason
            listed = await ask_orders(mes, keys, OrdersRequest(action=OrdersAction.LIST))
            assert [(o.id, o.state) for o in listed.orders] == [(1, OrderState.RUNNING), (3, OrderState.QUEUED)]
            assert [o.origin for o in listed.orders] == ["mes", "mes"]
    assert changes == ["changed"] * 3  # two adds and a cancel; refusals and listings change nothing


async def test_an_unreadable_request_is_refused_with_the_reason(service: OrdersService) -> None:
    reply_bytes = await service.answer(Request("engine_assembly/ctl/orders", "", b"\x93garbage"))
    from common.wire.messages import decode

    reply = decode(reply_bytes, OrdersReply)
    assert not reply.accepted and reply.reason.startswith("unreadable request")
    reply = decode(await service.answer(Request("k", "", encode(OrdersRequest(action=OrdersAction.LIST)))),
                   OrdersReply)
    assert reply.accepted and reply.orders == []


# --- tls: only an operator's certificate ----------------------------------------------------------

def _tls_station(tmp: Path) -> tuple[StationConfig, Model, Path]:
    text = (ROOT / "hubs.toml").read_text(encoding="utf-8")
    text, replaced = re.subn(r"(?ms)^\[security\]\n.*?(?=^(\[|# ---))", "", text)
    assert replaced == 1, "hubs.toml has no [security] section to replace"
    path = tmp / "hubs.toml"
    path.write_text(f'{text}\n[security]\nmode = "tls"\noperators = ["op"]\n', encoding="utf-8")
    config, model = load_station(path)
    certs = tmp / "certs"
    init_ca(certs, config.station.name, force=True)
    issue_for_station(certs, config, [identity_of(config, n) for n in ("controller", "pi-rsp", "op")])
    return config, model, certs


def test_the_access_control_lets_operators_and_nobody_else_query_ctl_orders(tmp_path: Path) -> None:
    config, model, _ = _tls_station(tmp_path)
    acl = access_control(config, model)
    rules = {r["id"]: r for r in acl["rules"]}
    queries = {p["subjects"][0]: [k for r in p["rules"] for k in rules[r]["key_exprs"]
                                  if "query" in rules[r]["messages"]]
               for p in acl["policies"] if p["id"].endswith("-sends")}
    orders = config.keys.ctl(ORDERS_KEY)
    assert orders in queries["operator-op"]
    covering = (orders, config.keys.ctl("**"), f"{config.keys.station}/**")
    # the operator, and the controller (which may query anything of its station); no hub
    assert {s for s, keys in queries.items() if set(covering) & set(keys)} == {"operator-op", "controller-decs"}


@pytest.mark.parametrize(("name", "answered"), [("op", True), ("pi-rsp", False)])
async def test_in_tls_mode_only_an_operator_certificate_gets_an_answer(tmp_path: Path, name: str,
                                                                       answered: bool) -> None:
    config, model, certs = _tls_station(tmp_path)
    store = StateStore(tmp_path / "controller.sqlite")
    service = OrdersService(OrderBook(store, model))
    port = free_port()
    base = config.loopback_network("controller", port)
    controller_config = station_zenoh_config(config, model, identity_of(config, "controller"), base, certs=certs)
    asker_config = station_zenoh_config(config, model, identity_of(config, name), base, certs=certs,
                                        connect=base.listen, listen=[])
    # The asker checks nothing itself: whatever stops it is the controller's access control.
    asker_config.insert_json5("access_control", json.dumps({"enabled": False}))
    request = OrdersRequest(action=OrdersAction.ADD, variant="light", origin=name)
    try:
        async with ZenohBus(controller_config) as controller_bus:
            service.declare(controller_bus, config.keys)
            async with ZenohBus(asker_config) as asker:
                replies = [await _ask_until_answered(asker, config.station.name, request)]
                replies += [await ask_orders(asker, config.keys, request, timeout=1.0) for _ in range(4)]
        queued = len(service.book.orders())
    finally:
        store.close()
    assert [r.accepted for r in replies] == [answered] * 5, [r.reason for r in replies]
    assert queued == (5 if answered else 0)
