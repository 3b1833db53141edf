"""The order book: the station's orders, persisted in the controller's SQLite file.

An order goes queued -> running -> done, or queued -> cancelled. At most one order runs: its
product is on the station. Each transition is one transaction of the controller's state file
(`StateStore`, WAL and `synchronous=FULL`), so a `kill -9` loses none that returned, and the
transitions that change the product commit the product's variables with them:

* `next()` (the station is free) takes the oldest queued order and, in the same commit, gives the
  product variables their start values (initial values, then the variant's parameters, then the
  order's) and stores the operations the order requests as the controller's requested operations.
* `finish(order, archive)` (every requested operation finished: the product left) stores the
  product's estimated state with the order, once, and in the same commit returns the product
  variables and operations to their initial values and requests nothing.

So a controller restarted mid-order finds the order running and its product's state as it was
persisted: it goes on with nothing redone and nothing skipped; restarted between two orders, it finds
the product reset and the next order still queued.

Cancelling a queued order drops it. A running order is not cancelled: its product is on the
station, half assembled, and only the station can take it off (stop its operations from the
console, or let it finish); the refusal says so.
"""

from __future__ import annotations

import json
import sqlite3
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from common.config.production import ProductionPlan
from common.model import Model, OperationState, Value
from common.wire.orders import Order, OrderState, ParameterValue
from controller.state import StateStore

REQUESTED_META = "requested"  # the controller's requested operations, as controller/service.py reads them
MAX_ADD = 1000  # orders one request may add: a typo must not queue a million
LIST_FINISHED = 50  # done and cancelled orders a listing shows, the newest

SCHEMA = """
CREATE TABLE IF NOT EXISTS orders (
    id INTEGER PRIMARY KEY,
    product_id TEXT NOT NULL UNIQUE,
    variant TEXT NOT NULL,
    parameters TEXT NOT NULL,
    state TEXT NOT NULL,
    origin TEXT NOT NULL,
    queued_at REAL NOT NULL,
    started_at REAL,
    finished_at REAL,
    archive TEXT,
    carried TEXT
);
CREATE INDEX IF NOT EXISTS orders_by_state ON orders(state, id);
"""
_COLUMNS = "id, product_id, variant, parameters, state, origin, queued_at, started_at, finished_at, archive, carried"
# A book written before a line's orders carried the product's state: the column it lacks.
_ADDED_COLUMNS = {"carried": "ALTER TABLE orders ADD COLUMN carried TEXT"}


class OrderError(ValueError):
    """A request the order book refuses; the message says why."""


@dataclass(frozen=True)
class OrderStart:
    """An order that just started: the operations to request and the product variables' values."""

    order: Order
    operations: tuple[str, ...]
    values: dict[str, Value]


@dataclass(frozen=True)
class OrderFinish:
    """An order that just finished: what was archived, and the product variables' values for the next."""

    order: Order
    archive: dict[str, Value]
    reset: dict[str, Value]


class OrderBook:
    """The orders of one station model, in `store`'s file. Every method commits what it changes."""

    def __init__(self, store: StateStore, model: Model, clock: Callable[[], float] = time.time) -> None:
        self.store = store
        self.db: sqlite3.Connection = store.db
        self.model = model
        self.clock = clock
        self.db.executescript(SCHEMA)
        present = {str(row[1]) for row in self.db.execute("PRAGMA table_info(orders)")}
        for column, alter in _ADDED_COLUMNS.items():
            if column not in present:
                self.db.execute(alter)

    # --- the queue ---------------------------------------------------------------------------
    def add(self, variant: str, *, product_id: str = "", parameters: Mapping[str, ParameterValue] | None = None,
            origin: str = "", count: int = 1, carried: Mapping[str, Value] | None = None) -> list[Order]:
        """Queue `count` orders of `variant`; the product ids are generated unless one order is given its own.
        `carried` (one order): the product's state from the previous station, kept with the order as it is."""
        parameters = dict(parameters or {})
        self._check(variant, parameters, count, product_id)
        if carried and count != 1:
            raise OrderError("a carried product state belongs to one product: give it with count 1")
        now = self.clock()
        with self.db:
            self.db.execute("BEGIN")
            (last,) = self.db.execute("SELECT COALESCE(MAX(id), 0) FROM orders").fetchone()
            ids = range(last + 1, last + 1 + count)
            for order_id in ids:
                self._insert(order_id, variant, product_id, parameters, origin, now, carried)
        return [self.get(order_id) for order_id in ids]

    def add_plan(self, plan: ProductionPlan) -> list[Order]:
        """Queue every order of `plan` in one commit: a controller killed while queueing it finds all or none."""
        for planned in plan.orders:
            self._check(planned.variant, dict(planned.parameters or {}), 1, planned.product_id)
        now = self.clock()
        with self.db:
            self.db.execute("BEGIN")
            (last,) = self.db.execute("SELECT COALESCE(MAX(id), 0) FROM orders").fetchone()
            ids = range(last + 1, last + 1 + len(plan.orders))
            for order_id, planned in zip(ids, plan.orders, strict=True):
                self._insert(order_id, planned.variant, planned.product_id, dict(planned.parameters or {}),
                             plan.source, now)
        return [self.get(order_id) for order_id in ids]

    def _insert(self, order_id: int, variant: str, product_id: str, parameters: Mapping[str, ParameterValue],
                origin: str, now: float, carried: Mapping[str, Value] | None = None) -> None:
        product = product_id or f"{self.model.name}-{order_id:05d}"
        try:
            self.db.execute(
                "INSERT INTO orders(id, product_id, variant, parameters, state, origin, queued_at, carried) "
                "VALUES(?, ?, ?, ?, ?, ?, ?, ?)",
                (order_id, product, variant, json.dumps(dict(parameters)), OrderState.QUEUED.value, origin, now,
                 json.dumps(dict(carried)) if carried else None))
        except sqlite3.IntegrityError:
            raise OrderError(f"product {product!r} already has an order") from None

    def put(self, order: Order) -> None:
        """Store `order` as it is (its id, state and times): a replay rebuilds a recorded run's orders."""
        with self.db:
            self.db.execute("BEGIN")
            self._insert(order.id, order.variant, order.product_id, order.parameters, order.origin, order.queued_at)
            self.db.execute("UPDATE orders SET state=?, started_at=? WHERE id=?",
                            (order.state.value, order.started_at, order.id))

    def cancel(self, order_id: int) -> Order:
        order = self.get(order_id)
        if order.state is OrderState.RUNNING:
            raise OrderError(f"order {order_id} is running: its product is on the station; stop its operations "
                             f"from the console, or let it finish")
        if order.state is not OrderState.QUEUED:
            raise OrderError(f"order {order_id} is already {order.state}")
        with self.db:
            self.db.execute("BEGIN")
            self.db.execute("UPDATE orders SET state=?, finished_at=? WHERE id=?",
                            (OrderState.CANCELLED.value, self.clock(), order_id))
        return self.get(order_id)

    def get(self, order_id: int) -> Order:
        row = self.db.execute(f"SELECT {_COLUMNS} FROM orders WHERE id=?", (order_id,)).fetchone()
        if row is None:
            raise OrderError(f"no order {order_id}")
        return _from_row(row)

    def orders_of(self, product_ids: Sequence[str]) -> list[Order]:
        """The orders of these products in any state, however old (a line controller asks for its products')."""
        rows = self.db.execute(f"SELECT {_COLUMNS} FROM orders WHERE product_id IN (SELECT value FROM json_each(?)) "
                               "ORDER BY id", (json.dumps(list(product_ids)),)).fetchall()
        return [_from_row(row) for row in rows]

    def orders(self, *, include_finished: bool = False) -> list[Order]:
        """The running order and the queue in order; with `include_finished` first the newest finished ones."""
        rows = []
        if include_finished:
            rows = self.db.execute(
                f"SELECT {_COLUMNS} FROM orders WHERE state IN (?, ?) ORDER BY id DESC LIMIT ?",
                (OrderState.DONE.value, OrderState.CANCELLED.value, LIST_FINISHED)).fetchall()[::-1]
        rows += self.db.execute(f"SELECT {_COLUMNS} FROM orders WHERE state IN (?, ?) ORDER BY id",
                                (OrderState.RUNNING.value, OrderState.QUEUED.value)).fetchall()
        return [_from_row(row) for row in rows]

    def done_orders(self) -> list[Order]:
        """Every done order, oldest first: read from the file, kept nowhere in memory."""
        return [_from_row(row) for row in self.db.execute(
            f"SELECT {_COLUMNS} FROM orders WHERE state=? ORDER BY id", (OrderState.DONE.value,))]

    def current(self) -> Order | None:
        """The running order: its product is on the station."""
        row = self.db.execute(f"SELECT {_COLUMNS} FROM orders WHERE state=?", (OrderState.RUNNING.value,)).fetchone()
        return None if row is None else _from_row(row)

    def queued(self) -> int:
        return self.count(OrderState.QUEUED)

    def count(self, state: OrderState) -> int:
        (count,) = self.db.execute("SELECT COUNT(*) FROM orders WHERE state=?", (state.value,)).fetchone()
        return int(count)

    def empty(self) -> bool:
        """No order was ever added (a fresh start)."""
        return self.db.execute("SELECT 1 FROM orders LIMIT 1").fetchone() is None

    # --- what the control loop calls -----------------------------------------------------------
    def next(self) -> OrderStart | None:
        """Start the oldest queued order when no order runs; None while one runs or none is queued."""
        if self.current() is not None:
            return None
        row = self.db.execute(f"SELECT {_COLUMNS} FROM orders WHERE state=? ORDER BY id LIMIT 1",
                              (OrderState.QUEUED.value,)).fetchone()
        if row is None:
            return None
        order = _from_row(row)
        operations = self.requested(order)
        values = self.start_values(order)
        with self.db:
            self.db.execute("BEGIN")
            self.db.execute("UPDATE orders SET state=?, started_at=? WHERE id=?",
                            (OrderState.RUNNING.value, self.clock(), order.id))
            self.store.write(values, {REQUESTED_META: list(operations)})
        return OrderStart(self.get(order.id), operations, values)

    def complete(self, order: Order, values: Mapping[str, Value]) -> bool:
        """Every operation `order` requests is finished in `values` (the controller's state)."""
        finished = OperationState.FINISHED.value
        return all(values.get(f"op.{name}") == finished for name in self.requested(order))

    def finish(self, order: Order, archive: Mapping[str, Value]) -> OrderFinish:
        """Mark the running `order` done with its product's state (`archive`: the controller's values; the
        product variables are kept). Once only: finishing a done order again changes nothing."""
        stored = self.get(order.id)
        reset = self.reset_values()
        if stored.state is OrderState.DONE:
            return OrderFinish(stored, self.archive(order.id), reset)
        if stored.state is not OrderState.RUNNING:
            raise OrderError(f"order {order.id} is {stored.state}, not running: it cannot finish")
        missing = [path for path in self.model.product_variables if path not in archive]
        if missing:
            raise OrderError(f"the archive of order {order.id} lacks product variables {', '.join(missing[:5])}")
        kept = {path: archive[path] for path in self.model.product_variables}
        with self.db:
            self.db.execute("BEGIN")
            self.db.execute("UPDATE orders SET state=?, finished_at=?, archive=? WHERE id=?",
                            (OrderState.DONE.value, self.clock(), json.dumps(kept), order.id))
            self.store.write(reset, {REQUESTED_META: []})
        return OrderFinish(self.get(order.id), kept, reset)

    def archive(self, order_id: int) -> dict[str, Value]:
        """The product's state when order `order_id` finished ({} before)."""
        row = self.db.execute("SELECT archive FROM orders WHERE id=?", (order_id,)).fetchone()
        if row is None:
            raise OrderError(f"no order {order_id}")
        return {} if row[0] is None else dict(json.loads(row[0]))

    # --- the model's side ----------------------------------------------------------------------
    def requested(self, order: Order) -> tuple[str, ...]:
        return self.model.variant_by_name[order.variant].requested(self.model.operations)

    def reset_values(self) -> dict[str, Value]:
        """The product variables and operation states at their initial values."""
        return {path: self.model.variables[path].initial for path in self.model.product_variables}

    def start_values(self, order: Order) -> dict[str, Value]:
        return {**self.reset_values(), **self.model.variant_by_name[order.variant].parameters, **order.parameters}

    def _check(self, variant: str, parameters: Mapping[str, ParameterValue], count: int, product_id: str) -> None:
        chosen = self.model.variant_by_name.get(variant)
        if chosen is None:
            raise OrderError(f"model {self.model.name} has no variant {variant!r} "
                             f"(its variants: {', '.join(self.model.variant_by_name)})")
        if not 1 <= count <= MAX_ADD:
            raise OrderError(f"count {count}: add 1 to {MAX_ADD} orders at a time")
        if product_id and count != 1:
            raise OrderError("a product id names one order: give it with count 1")
        for path, value in parameters.items():
            if path not in chosen.parameters:
                known = ", ".join(chosen.parameters) or "none"
                raise OrderError(f"variant {variant} has no parameter {path} (its parameters: {known})")
            domain = self.model.variables[path].domain
            if value not in domain:
                raise OrderError(f"parameter {path} = {value!r} is outside {domain.describe()}")


def _from_row(row: Sequence[object]) -> Order:
    order_id, product_id, variant, parameters, state, origin, queued_at, started_at, finished_at, archive, carried = row
    assert isinstance(parameters, str)
    return Order(id=int(str(order_id)), product_id=str(product_id), variant=str(variant),
                 parameters=json.loads(parameters), state=OrderState(str(state)), origin=str(origin),
                 queued_at=float(str(queued_at)), started_at=_time(started_at), finished_at=_time(finished_at),
                 archive=_values(archive), carried=_values(carried))


def _values(column: object) -> dict[str, Value]:
    return {} if column is None else dict(json.loads(str(column)))


def _time(value: object) -> float | None:
    return None if value is None else float(str(value))
