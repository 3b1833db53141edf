"""The line controller's SQLite: every product's visits along the route, and where each handover stands.

A visit is one product at one station: `pending` (not handed over yet), `added` (the station's order book
has its order), `done` (the station finished it: the product left). Each change is one commit
(`synchronous=FULL`, WAL), so a line controller killed at any point finds every handover as it last
knew it; what it does next is idempotent (deploy/line/handover.py), so a change it made on a station but
had not committed yet is found there, not made twice.
"""

from __future__ import annotations

import enum
import json
import sqlite3
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from common.wire.orders import ParameterValue

SCHEMA = """
CREATE TABLE IF NOT EXISTS visits (
    product_id TEXT NOT NULL,
    step INTEGER NOT NULL,
    station TEXT NOT NULL,
    variant TEXT NOT NULL,
    state TEXT NOT NULL,
    station_order INTEGER,
    added_at REAL,
    started_at REAL,
    finished_at REAL,
    carried TEXT NOT NULL DEFAULT '{}',
    PRIMARY KEY (product_id, step)
);
CREATE INDEX IF NOT EXISTS visits_by_state ON visits(state, station);
"""
_COLUMNS = "product_id, step, station, variant, state, station_order, added_at, started_at, finished_at, carried"


class VisitState(enum.StrEnum):
    PENDING = "pending"  # waits for the previous station (or, at the first, for its turn)
    ADDED = "added"  # the station's order book has the order
    DONE = "done"  # the station finished it


@dataclass(frozen=True)
class Visit:
    product_id: str
    step: int  # the station's index on the route
    station: str
    variant: str
    state: VisitState
    station_order: int | None  # the order's id in the station's book
    added_at: float | None
    started_at: float | None  # on the station's clock, as its book reports
    finished_at: float | None
    # The product's state as the previous station archived it, which its order here carries ({} at the first)
    carried: dict[str, ParameterValue]


class LineStore:
    def __init__(self, path: Path, clock: Callable[[], float] = time.time) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self.clock = clock
        self.db = sqlite3.connect(path, isolation_level=None)
        self.db.execute("PRAGMA journal_mode=WAL")
        self.db.execute("PRAGMA synchronous=FULL")
        self.db.executescript(SCHEMA)

    def close(self) -> None:
        self.db.close()

    def empty(self) -> bool:
        return self.db.execute("SELECT 1 FROM visits LIMIT 1").fetchone() is None

    def add_products(self, product_ids: Sequence[str], route: Sequence[tuple[str, str]]) -> None:
        """Each product with one pending visit per (station, variant) of the route, in one commit."""
        with self.db:
            self.db.execute("BEGIN")
            for product_id in product_ids:
                for step, (station, variant) in enumerate(route):
                    self.db.execute("INSERT INTO visits(product_id, step, station, variant, state) VALUES(?,?,?,?,?)",
                                    (product_id, step, station, variant, VisitState.PENDING.value))

    def visits(self, state: VisitState | None = None) -> list[Visit]:
        where, args = ("WHERE state=?", (state.value,)) if state is not None else ("", ())
        rows = self.db.execute(f"SELECT {_COLUMNS} FROM visits {where} ORDER BY product_id, step", args).fetchall()
        return [_visit(row) for row in rows]

    def ready(self) -> list[Visit]:
        """Pending visits whose product finished the previous station (or that are the first of the route)."""
        rows = self.db.execute(
            f"SELECT {', '.join('v.' + c.strip() for c in _COLUMNS.split(','))} FROM visits v "
            "LEFT JOIN visits p ON p.product_id = v.product_id AND p.step = v.step - 1 "
            "WHERE v.state = ? AND (v.step = 0 OR p.state = ?) ORDER BY v.product_id, v.step",
            (VisitState.PENDING.value, VisitState.DONE.value)).fetchall()
        return [_visit(row) for row in rows]

    def previous(self, visit: Visit) -> Visit | None:
        row = self.db.execute(f"SELECT {_COLUMNS} FROM visits WHERE product_id=? AND step=?",
                              (visit.product_id, visit.step - 1)).fetchone()
        return None if row is None else _visit(row)

    def mark_added(self, visit: Visit, station_order: int, carried: dict[str, ParameterValue]) -> None:
        with self.db:
            self.db.execute("BEGIN")
            self.db.execute("UPDATE visits SET state=?, station_order=?, added_at=?, carried=? "
                            "WHERE product_id=? AND step=? AND state=?",
                            (VisitState.ADDED.value, station_order, self.clock(), json.dumps(carried),
                             visit.product_id, visit.step, VisitState.PENDING.value))

    def mark_done(self, visit: Visit, started_at: float | None, finished_at: float | None,
                  archive: Mapping[str, ParameterValue] | None = None) -> None:
        """The station finished the product; in the same commit its archived state becomes what the product
        carries to its next visit."""
        with self.db:
            self.db.execute("BEGIN")
            changed = self.db.execute("UPDATE visits SET state=?, started_at=?, finished_at=? "
                                      "WHERE product_id=? AND step=? AND state=?",
                                      (VisitState.DONE.value, started_at, finished_at, visit.product_id,
                                       visit.step, VisitState.ADDED.value)).rowcount
            if changed:
                self.db.execute("UPDATE visits SET carried=? WHERE product_id=? AND step=? AND state=?",
                                (json.dumps(dict(archive or {})), visit.product_id, visit.step + 1,
                                 VisitState.PENDING.value))

    def products_left(self, last_step: int) -> tuple[int, int]:
        """(products that left the last station, products)."""
        (done,) = self.db.execute("SELECT COUNT(*) FROM visits WHERE step=? AND state=?",
                                  (last_step, VisitState.DONE.value)).fetchone()
        (total,) = self.db.execute("SELECT COUNT(DISTINCT product_id) FROM visits").fetchone()
        return int(done), int(total)


def _visit(row: Sequence[object]) -> Visit:
    product_id, step, station, variant, state, order, added, started, finished, carried = row
    return Visit(str(product_id), int(str(step)), str(station), str(variant), VisitState(str(state)),
                 None if order is None else int(str(order)), _time(added), _time(started), _time(finished),
                 json.loads(str(carried)))


def _time(value: object) -> float | None:
    return None if value is None else float(str(value))


def open_read_only(path: Path) -> sqlite3.Connection:
    """A reader beside the line controller (`hubctl line up`'s overview): never writes, never blocks it."""
    return sqlite3.connect(f"file:{path}?mode=ro", uri=True)
