"""line.toml's checks, and the line controller's handovers against real order books (no network): in route
order, once each, and idempotent through a lost reply, a restart of the line controller and an unreachable
station."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import msgspec
import pytest

from common.config.errors import ConfigError
from common.line.config import load_line, parse_line
from common.wire.orders import Order, OrdersAction, OrdersReply, OrdersRequest, OrderState
from controller.production.book import LIST_FINISHED, OrderBook
from controller.production.service import OrdersService
from controller.state import StateStore
from deploy.line.handover import Handover
from deploy.line.store import LineStore, VisitState
from deploy.orders_cli import order_row
from deploy.remote.units import DEFAULT_SYSTEMD, line_controller_unit, local_systemd_version, write_units
from tests.line_station.model import BOLTS, bolt, build_model
from tests.line_station.site import write_line
from tests.test_units import unit_problems

GOOD = """
[line]
name = "demo"
router = "r1"

[routers.r1]
listen = ["tcp/127.0.0.1:7501"]

[stations.s1]
config = "hubs.toml"
router = "r1"

[route]
stations = ["s1"]
"""


def problems(text: str, tmp_path: Path) -> list[str]:
    (tmp_path / "hubs.toml").write_text("")
    with pytest.raises(ConfigError) as error:
        parse_line(text, tmp_path / "line.toml")
    return [str(p) for p in error.value.problems]


def test_a_written_line_loads(tmp_path):
    line = load_line(write_line(tmp_path, 3))
    assert line.route == ("s1", "s2", "s3")
    assert [line.stations[s].router for s in line.route] == ["r1", "r2", "r1"]
    assert line.next_station("s2") == "s3" and line.next_station("s3") is None
    assert line.db == tmp_path / "line.sqlite"


def test_errors_name_file_line_and_key(tmp_path):
    (tmp_path / "hubs.toml").write_text("")
    parse_line(GOOD, tmp_path / "line.toml")  # the base is good
    bad = GOOD.replace('router = "r1"\n\n[route]', 'router = "r9"\ncolour = "red"\n\n[route]')
    found = problems(bad, tmp_path)
    file = str(tmp_path / "line.toml")
    assert f"{file}:11: stations.s1.router: no router 'r9' (routers: r1)" in found
    assert f"{file}:12: stations.s1.colour: unknown key (known keys: config, router, variant)" in found


def test_route_and_routers_are_checked(tmp_path):
    found = problems(GOOD.replace('stations = ["s1"]', 'stations = ["s1", "s2", "s1"]')
                     .replace('listen = ["tcp/127.0.0.1:7501"]', "listen = []"), tmp_path)
    assert any("route.stations: no station 's2'" in p for p in found)
    assert any("route.stations: station 's1' twice" in p for p in found)
    assert any("routers.r1: a router needs at least one `listen` endpoint" in p for p in found)
    assert any("missing section [line]" in p for p in problems("[route]\nstations = []\n", tmp_path))


class Books:
    """Each station's real order book behind its real orders service; a reply can be lost."""

    def __init__(self, directory: Path, stations: list[str]) -> None:
        self.model = build_model()
        self.books = {s: OrderBook(StateStore(directory / f"{s}.sqlite"), self.model) for s in stations}
        self.services = {s: OrdersService(book) for s, book in self.books.items()}
        self.down: set[str] = set()
        self.lose_add_reply: set[str] = set()  # the next add to these stations is applied, its reply lost
        self.asked: list[tuple[str, str]] = []

    async def ask(self, station: str, request: OrdersRequest) -> OrdersReply | None:
        self.asked.append((station, request.action.value))
        if station in self.down:
            return None
        reply = self.services[station].apply(request)
        if station in self.lose_add_reply and request.action is OrdersAction.ADD:
            self.lose_add_reply.discard(station)
            return None  # applied, but the reply never came back
        return reply

    def finish_running(self, station: str) -> str | None:
        """The station finishes its next order (started by its control loop as it would be)."""
        book = self.books[station]
        start = book.next()
        if start is None:
            return None
        archive = {**start.values, **{bolt(i): "tightened" for i in BOLTS}}
        book.finish(start.order, archive)
        return start.order.product_id

    def orders(self, station: str) -> dict[str, OrderState]:
        return {o.product_id: o.state for o in self.books[station].orders(include_finished=True)}


ROUTE = [("s1", "default"), ("s2", "default"), ("s3", "default")]


async def test_products_move_along_the_route_once_each(tmp_path):
    books = Books(tmp_path, ["s1", "s2", "s3"])
    store = LineStore(tmp_path / "line.sqlite")
    store.add_products(["p1", "p2"], ROUTE)
    handover = Handover(store, books)
    await handover.round()
    assert books.orders("s1") == {"p1": OrderState.QUEUED, "p2": OrderState.QUEUED}
    assert books.orders("s2") == {}  # nothing reaches s2 before s1 finished it
    assert books.finish_running("s1") == "p1"
    await handover.round()  # p1 seen done at s1...
    await handover.round()  # ...and handed to s2
    assert books.orders("s2") == {"p1": OrderState.QUEUED}
    for station in ("s1", "s2", "s3", "s2", "s3"):
        books.finish_running(station)
        await handover.round()
        await handover.round()
    assert store.products_left(2) == (2, 2)
    for station in ("s1", "s2", "s3"):
        assert books.orders(station) == {"p1": OrderState.DONE, "p2": OrderState.DONE}


async def test_a_lost_reply_and_a_restart_hand_over_once(tmp_path):
    books = Books(tmp_path, ["s1", "s2", "s3"])
    store = LineStore(tmp_path / "line.sqlite")
    store.add_products(["p1"], ROUTE)
    books.lose_add_reply.add("s1")
    await Handover(store, books).round()  # s1 queued it; the reply was lost
    assert books.orders("s1") == {"p1": OrderState.QUEUED}
    assert next(v.state for v in store.visits()) is VisitState.PENDING
    store.close()
    store = LineStore(tmp_path / "line.sqlite")  # the line controller restarted
    await Handover(store, books).round()
    assert store.visits()[0].state is VisitState.ADDED
    assert len(books.books["s1"].orders(include_finished=True)) == 1  # found there, not added again
    assert ("s1", "add") in books.asked and books.asked.count(("s1", "add")) == 1


async def test_an_unreachable_station_waits_then_gets_its_product(tmp_path):
    books = Books(tmp_path, ["s1", "s2", "s3"])
    store = LineStore(tmp_path / "line.sqlite")
    store.add_products(["p1"], ROUTE)
    handover = Handover(store, books)
    await handover.round()
    books.finish_running("s1")
    books.down.add("s2")
    await handover.round()
    result = await handover.round()
    assert result.unreachable == {"s2"} and handover.unreachable == {"s2"}
    assert books.orders("s2") == {}
    books.down.clear()
    await handover.round()
    assert handover.unreachable == set()
    assert books.orders("s2") == {"p1": OrderState.QUEUED}


async def test_the_product_state_travels_with_it_to_the_next_station(tmp_path):
    books = Books(tmp_path, ["s1", "s2", "s3"])
    store = LineStore(tmp_path / "line.sqlite")
    store.add_products(["p1"], ROUTE)
    handover = Handover(store, books)
    await handover.round()
    books.finish_running("s1")  # archives both bolts tightened
    await handover.round()
    await handover.round()
    (at_s1,) = books.books["s1"].orders_of(["p1"])
    assert (at_s1.archive[bolt(1)], at_s1.archive[bolt(2)]) == ("tightened", "tightened")
    (at_s2,) = books.books["s2"].orders(include_finished=True)
    assert (at_s2.product_id, at_s2.carried, at_s2.parameters) == ("p1", at_s1.archive, {})
    assert "carried: engine.bolt1_e=tightened engine.bolt2_e=tightened" in order_row(at_s2)  # hubctl orders list
    assert store.visits()[1].carried == at_s1.archive  # in the line controller's file too
    # kept in s2's file: a controller restarted reads it back
    again = OrderBook(books.books["s2"].store, books.model)
    assert again.get(at_s2.id).carried == at_s1.archive
    # s2's product variables start from its own variant, not from what was carried (kept, not applied)
    start = books.books["s2"].next()
    assert start is not None and start.values[bolt(1)] == "placed"
    books.books["s2"].finish(start.order, {**start.values, bolt(1): "tightened"})
    await handover.round()
    await handover.round()
    (at_s3,) = books.books["s3"].orders()
    assert (at_s3.carried[bolt(1)], at_s3.carried[bolt(2)]) == ("tightened", "placed")  # s2's archive, not s1's


async def test_a_product_finished_before_many_other_orders_is_still_found(tmp_path):
    """The line controller asks for its products' orders, not for the newest finished ones: a station that
    finished LIST_FINISHED other orders after the product, while the line controller was down, still says
    the product is done."""
    books = Books(tmp_path, ["s1", "s2", "s3"])
    store = LineStore(tmp_path / "line.sqlite")
    store.add_products(["p1"], ROUTE)
    await Handover(store, books).round()
    assert books.finish_running("s1") == "p1"
    books.books["s1"].add("default", count=LIST_FINISHED + 5, origin="an MES")
    while books.finish_running("s1") is not None:
        pass
    assert "p1" not in books.orders("s1")  # gone from the newest finished a plain listing shows
    await Handover(store, books).round()  # the line controller is back
    await Handover(store, books).round()
    assert books.orders("s2") == {"p1": OrderState.QUEUED}


def test_an_order_book_written_before_carried_states_opens_and_keeps_its_orders(tmp_path):
    path = tmp_path / "old.sqlite"
    old = sqlite3.connect(path)
    old.executescript(OLD_ORDERS_SCHEMA)
    old.execute("INSERT INTO orders(id, product_id, variant, parameters, state, origin, queued_at) "
                "VALUES(1, 'p1', 'default', '{}', 'queued', '', 1.0)")
    old.commit()
    old.close()
    book = OrderBook(StateStore(path), build_model())
    assert [(o.product_id, o.carried) for o in book.orders()] == [("p1", {})]
    (added,) = book.add("default", product_id="p2", carried={bolt(1): "tightened"})
    assert book.get(added.id).carried == {bolt(1): "tightened"}


def test_requests_and_orders_of_a_peer_without_the_new_fields_still_decode():
    old_request = msgspec.json.encode({"action": "list", "include_finished": True})
    assert msgspec.json.decode(old_request, type=OrdersRequest).product_ids == []
    old_order = msgspec.json.encode({"id": 1, "product_id": "p1", "variant": "default", "state": "done"})
    order = msgspec.json.decode(old_order, type=Order)
    assert (order.carried, order.archive) == ({}, {})


OLD_ORDERS_SCHEMA = """
CREATE TABLE orders (
    id INTEGER PRIMARY KEY, product_id TEXT NOT NULL UNIQUE, variant TEXT NOT NULL, parameters TEXT NOT NULL,
    state TEXT NOT NULL, origin TEXT NOT NULL, queued_at REAL NOT NULL, started_at REAL, finished_at REAL,
    archive TEXT
);
"""


@pytest.mark.parametrize(("db", "storage"), [
    ("var/line.sqlite", "ReadWritePaths=/etc/statehub/var"),  # beside line.toml, as on the target
    ("/var/lib/statehub-line/line.sqlite", "StateDirectory=statehub-line"),  # systemd creates it
])
def test_the_line_controller_unit_loads_cleanly_and_may_write_its_db(tmp_path, db, storage):
    path = write_line(tmp_path, 2, tls=True)
    path.write_text(path.read_text().replace('db = "line.sqlite"', f'db = "{db}"', 1))
    line = load_line(path)
    base = tmp_path / "opt" / "line"
    python = base / "current" / "venv" / "bin" / "python"
    python.parent.mkdir(parents=True)
    python.write_text("#!/bin/sh\nexit 0\n")
    python.chmod(0o755)
    version = local_systemd_version() or DEFAULT_SYSTEMD
    unit = line_controller_unit(line, "/etc/statehub/line.toml", base=str(base), systemd_version=version)
    assert unit.name == "statehub-line-controller.service"
    assert "-m deploy.line.controller --config /etc/statehub/line.toml --certs" in unit.text
    assert "Type=notify" in unit.text and "WatchdogSec=" in unit.text and "ProtectSystem=strict" in unit.text
    assert storage in unit.text.splitlines()
    (written,) = write_units([unit], tmp_path / "units")
    assert unit_problems(written, version) == []  # systemd-analyze verify where it is installed
