"""`hubctl orders add|list|cancel`, and the production options of `hubctl up` (`--orders N --mix ...`).

`orders` talks to the running controller over `{station}/ctl/orders` (controller/production/service.py),
connecting as the console does: to the controller's listeners of hubs.toml or `--connect`, and in
`tls` mode with an operator's certificate (`--as`, `--certs`).
"""

from __future__ import annotations

import argparse
import asyncio
import sys

from common.config.hubs_toml import StationConfig
from common.config.modes import NetworkMode
from common.config.production import ProductionPlan, plan_from_options
from common.model import Model
from common.wire.orders import Order, OrdersAction, OrdersReply, OrdersRequest, ParameterValue


def add_production_options(up: argparse.ArgumentParser) -> None:
    up.add_argument("--orders", type=int, metavar="N",
                    help="run N orders, one product after another (default: [production] of hubs.toml, else the "
                         "model's operations once)")
    up.add_argument("--mix", metavar="VARIANT:WEIGHT,...",
                    help="with --orders: the variants, repeating, e.g. full:3,light:1 (default: [production] mix, "
                         "else the model's first variant)")


def production_plan(args: argparse.Namespace, config: StationConfig, model: Model) -> ProductionPlan | None:
    """The orders `hubctl up` queues at its start (ProductionError: a bad option, variant or parameter)."""
    return plan_from_options(args.orders, args.mix, config.production, model, config.path)


def parameter(text: str) -> tuple[str, ParameterValue]:
    """`PATH=VALUE` of `--param`, the value as the model spells it (true/false, an integer, a name)."""
    path, sep, value = text.partition("=")
    if not sep or not path.strip():
        raise argparse.ArgumentTypeError(f"{text!r}: expected PATH=VALUE, e.g. engine.count_bolts_e=22")
    value = value.strip()
    typed: ParameterValue = value
    if value in ("true", "false"):
        typed = value == "true"
    elif value.lstrip("-").isdigit():
        typed = int(value)
    return path.strip(), typed


def register_orders_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    orders = sub.add_parser("orders", help="add, list or cancel the running controller's orders")
    orders.add_argument("--config", default="hubs.toml", help="the station's hubs.toml (default: ./hubs.toml)")
    orders.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                        help="the controller's zenoh endpoint (default: its listeners in hubs.toml)")
    orders.add_argument("--as", dest="operator", metavar="OPERATOR",
                        help="with [security] mode = \"tls\": whose operator certificate to present")
    orders.add_argument("--certs", metavar="DIR", help="the certificate directory (default: [security] certs)")
    actions = orders.add_subparsers(dest="orders_action", required=True)
    add = actions.add_parser("add", help="queue orders of a variant")
    add.add_argument("variant")
    add.add_argument("--count", type=int, default=1, help="this many orders (default 1)")
    add.add_argument("--product", default="", help="the product's id (one order; default: generated)")
    add.add_argument("--param", action="append", default=[], type=parameter, metavar="PATH=VALUE",
                     help="a parameter of the variant, overridden (repeatable)")
    listing = actions.add_parser("list", help="the running order and the queue")
    listing.add_argument("--all", action="store_true", help="the newest finished and cancelled orders too")
    cancel = actions.add_parser("cancel", help="cancel a queued order")
    cancel.add_argument("order", type=int)
    orders.set_defaults(func=cmd_orders)


def request_of(args: argparse.Namespace, origin: str) -> OrdersRequest:
    action = OrdersAction(args.orders_action)
    if action is OrdersAction.ADD:
        return OrdersRequest(action=action, variant=args.variant, count=args.count, product_id=args.product,
                             parameters=dict(args.param), origin=origin)
    if action is OrdersAction.CANCEL:
        return OrdersRequest(action=action, order=args.order, origin=origin)
    return OrdersRequest(action=action, include_finished=args.all, origin=origin)


def order_row(order: Order) -> str:
    parameters = " ".join(f"{k}={v}" for k, v in sorted(order.parameters.items()))
    row = f"{order.id:>5}  {order.state:<9}  {order.variant:<10}  {order.product_id}" + (
        f"  {parameters}" if parameters else "")
    if order.carried:  # a line's product: its state as the previous station archived it
        row += "\n       carried: " + " ".join(f"{k}={v}" for k, v in sorted(order.carried.items()))
    return row


def print_reply(reply: OrdersReply) -> int:
    if not reply.accepted:
        print(f"hubctl orders: refused: {reply.reason}", file=sys.stderr)
        return 1
    for order in reply.orders:
        print(order_row(order))
    if reply.reason:
        print(reply.reason)
    return 0


def cmd_orders(args: argparse.Namespace) -> int:
    from common.bus.station_net import station_zenoh_config
    from common.bus.zenoh_bus import ZenohBus
    from common.config.hubs_toml import NetworkConfig, load_station
    from common.config.security import operator_identity
    from controller.console.link import origin
    from controller.console.station import controller_endpoints
    from controller.production.client import ask_orders

    station, model = load_station(args.config)
    endpoints = list(args.connect) or list(controller_endpoints(station))
    network = NetworkConfig(mode=NetworkMode.PEER, listen=[], connect=endpoints, lease_ms=station.network.lease_ms)
    zconfig = station_zenoh_config(station, model, operator_identity(station, args.operator), network,
                                   certs=args.certs)
    request = request_of(args, origin())

    async def ask() -> OrdersReply:
        async with ZenohBus(zconfig) as bus:
            return await ask_orders(bus, station.keys, request)

    return print_reply(asyncio.run(ask()))
