"""A run's recording files on disk: created, appended to one transaction per batch, continued in a next part
file beyond `max_bytes`, completed when the run ends; the directory pruned to `keep` recording files.

The writer process (writer_process.py) is the only one that appends. RecordingWriter creates the first file
itself, before it starts that process, so that a directory that cannot be written is known at once.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import sqlite3
import time
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import msgspec

from controller.recording.schema import DDL, KIND_KEY_INDEX, SUFFIX, RunMeta

log = logging.getLogger("statehub.recording")

Row = tuple[float, str, str, Any]  # t, kind, key, data (bytes, or a buffer of them)


def run_file_name(meta: RunMeta, part: int = 1) -> str:
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(meta.started))
    station = re.sub(r"[^A-Za-z0-9_.-]", "_", meta.station) or "station"
    suffix = "" if part == 1 else f".part{part}"
    return f"{stamp}-{station}-{meta.run}{suffix}{SUFFIX}"


def write_meta(connection: sqlite3.Connection, meta: RunMeta) -> None:
    connection.executemany("INSERT OR REPLACE INTO run_meta (key, value) VALUES (?, ?)",
                           [(k, json.dumps(v)) for k, v in msgspec.to_builtins(meta).items()])


def open_file(path: Path, meta: RunMeta) -> sqlite3.Connection:
    """Open (creating it if new) a recording file and write `meta` into it."""
    connection = sqlite3.connect(path, check_same_thread=False, isolation_level=None)
    try:
        connection.execute("PRAGMA journal_mode=WAL")  # readers (timeline, runs) see committed batches
        connection.execute("PRAGMA synchronous=NORMAL")
        connection.executescript(DDL)
        connection.isolation_level = "DEFERRED"  # `with connection` opens and commits a transaction
        with connection:
            write_meta(connection, meta)
    except sqlite3.Error:
        connection.close()
        raise
    return connection


def complete(connection: sqlite3.Connection) -> None:
    """Make a part file that will not grow any more self-contained and quick to query."""
    connection.execute(KIND_KEY_INDEX)  # kept up to date while writing, it doubled the cost of an insert
    connection.execute("PRAGMA journal_mode=DELETE")


def prune(directory: Path, keep: int, current: Path) -> None:
    """Delete the oldest recordings beyond `keep` (never `current`, the file being written)."""
    files = sorted(directory.glob(f"*{SUFFIX}"), key=lambda p: (p.stat().st_mtime, p.name))
    excess = len(files) - keep
    for old in files:
        if excess <= 0:
            break
        if old == current:
            continue
        for suffix in ("", "-wal", "-shm"):
            with contextlib.suppress(FileNotFoundError):
                os.unlink(f"{old}{suffix}")
        log.info("recording: deleted %s (keep %d files)", old, keep)
        excess -= 1


class RunFiles:
    """The files of one run being written, from its first part (already created) on."""

    def __init__(self, path: Path, meta: RunMeta, *, max_bytes: int, keep: int) -> None:
        self.directory = path.parent
        self.meta = meta
        self.max_bytes = max_bytes
        self.keep = keep
        self.current = path
        self._connection = open_file(path, meta)

    def write(self, rows: Iterable[Row]) -> None:
        """One transaction; beyond `max_bytes` the run goes on in the next part file."""
        connection = self._connection
        with connection:
            connection.executemany("INSERT INTO events (t, kind, key, data) VALUES (?, ?, ?, ?)", rows)
        if self._size() > self.max_bytes:
            self._rotate()

    def update_meta(self, fields: Mapping[str, Any]) -> None:
        for name, value in fields.items():
            setattr(self.meta, name, value)
        with self._connection:
            write_meta(self._connection, self.meta)

    def close(self) -> None:
        """The run's end (or the end of what was received): the meta, the index, one self-contained file."""
        try:
            with self._connection:
                write_meta(self._connection, self.meta)
            complete(self._connection)
        finally:
            self._connection.close()

    def _size(self) -> int:
        pages = self._connection.execute("PRAGMA page_count").fetchone()[0]
        return int(pages) * int(self._connection.execute("PRAGMA page_size").fetchone()[0])

    def _rotate(self) -> None:
        complete(self._connection)
        self._connection.close()
        self.meta.part += 1
        self.current = self.directory / run_file_name(self.meta, self.meta.part)
        self._connection = open_file(self.current, self.meta)
        prune(self.directory, self.keep, self.current)
