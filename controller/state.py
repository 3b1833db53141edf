"""Persistence of the controller's own state: estimated variables, operation states and requests.

SQLite in WAL mode, one transaction per change set, `synchronous=FULL`: the WAL is synced
to disk at every commit, so neither a `kill -9` nor a power cut loses a save that returned
(the state is a few hundred rows changed a few times a second: the sync costs nothing that
matters, while NORMAL may lose the last commits on a power cut).

Loading checks every stored value against the current model: a variable the model no
longer has, or a value outside its domain, is reported and skipped rather than restored.
"""

from __future__ import annotations

import json
import logging
import sqlite3
from collections.abc import Mapping
from pathlib import Path

from common.model import Model, Value

log = logging.getLogger(__name__)

SCHEMA = """
CREATE TABLE IF NOT EXISTS variables (path TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
"""


class StateStore:
    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.db = sqlite3.connect(self.path, isolation_level=None)
        self.db.execute("PRAGMA journal_mode=WAL")
        self.db.execute("PRAGMA synchronous=FULL")
        self.db.executescript(SCHEMA)

    def close(self) -> None:
        self.db.close()

    def save(self, values: Mapping[str, Value], meta: Mapping[str, object] | None = None) -> None:
        if not values and not meta:
            return
        with self.db:
            self.db.execute("BEGIN")
            self.write(values, meta)

    def write(self, values: Mapping[str, Value], meta: Mapping[str, object] | None = None) -> None:
        """`save` inside a transaction the caller holds: the order book commits an order's transition and
        the values it gives the product variables at once (controller/production/book.py)."""
        self.db.executemany(
            "INSERT INTO variables(path, value) VALUES(?, ?) ON CONFLICT(path) DO UPDATE SET value=excluded.value",
            [(p, json.dumps(v)) for p, v in values.items()],
        )
        if meta:
            self.db.executemany(
                "INSERT INTO meta(key, value) VALUES(?, ?) ON CONFLICT(key) DO UPDATE SET value=excluded.value",
                [(k, json.dumps(v)) for k, v in meta.items()],
            )

    def load(self, model: Model) -> tuple[dict[str, Value], list[str]]:
        """The stored values that fit the model, and a note for each one that does not."""
        values: dict[str, Value] = {}
        notes: list[str] = []
        for path, text in self.db.execute("SELECT path, value FROM variables"):
            var = model.variables.get(path)
            if var is None:
                notes.append(f"{self.path}: stored variable {path} is not in model {model.name!r}: ignored")
                continue
            value = json.loads(text)
            if value not in var.domain:
                notes.append(f"{self.path}: stored {path}={value!r} is outside {var.domain.describe()}: ignored")
                continue
            values[path] = value
        return values, notes

    def meta(self, key: str, default: object = None) -> object:
        row = self.db.execute("SELECT value FROM meta WHERE key=?", (key,)).fetchone()
        return default if row is None else json.loads(row[0])

    def has_state(self) -> bool:
        return self.db.execute("SELECT 1 FROM variables LIMIT 1").fetchone() is not None
