"""Writing a run recording without ever blocking the caller.

`RecordingWriter.put` appends a record to a queue (a deque append: no lock, no I/O) and returns; a
writer thread drains the queue in batches, each in one SQLite transaction. If the disk is slower than
the records come, the queue grows up to `queue_limit` records and further ones are dropped and counted
(`RunMeta.dropped`): the controller's tick never waits for the disk.

A run's file is bounded by `max_bytes`: beyond it the run goes on in a next part file (the same `run`
id, `part` + 1). The directory keeps at most `keep` recording files: the oldest are deleted, never the
one being written.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import sqlite3
import threading
import time
import uuid
from collections import deque
from pathlib import Path
from typing import Any

import msgspec

from .schema import DDL, KIND_KEY_INDEX, SUFFIX, RecordKind, RunMeta

log = logging.getLogger("statehub.recording")

RECORDING_DIR_ENV = "STATEHUB_RECORDING_DIR"  # overrides [controller.recording] dir (the test suite sets it)
FLUSH_S = 0.25  # the writer wakes this often: a batch per wake-up
QUEUE_LIMIT = 200_000  # records waiting for the disk before new ones are dropped
_META = object()  # queue marker: a RunMeta update


def recording_dir(configured: str) -> Path:
    """Where runs are recorded: `configured` ([controller.recording] dir) unless $STATEHUB_RECORDING_DIR says."""
    return Path(os.environ.get(RECORDING_DIR_ENV) or configured)


def run_file_name(meta: RunMeta, part: int = 1) -> str:
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(meta.started))
    station = re.sub(r"[^A-Za-z0-9_.-]", "_", meta.station) or "station"
    suffix = "" if part == 1 else f".part{part}"
    return f"{stamp}-{station}-{meta.run}{suffix}{SUFFIX}"


class RecordingWriter:
    """One run's recording in `directory`; `path` is its first part file."""

    def __init__(self, directory: str | Path, meta: RunMeta, *, max_bytes: int, keep: int,
                 flush_s: float = FLUSH_S, queue_limit: int = QUEUE_LIMIT) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        if not meta.run:
            meta.run = uuid.uuid4().hex[:8]
        self.meta = meta
        self.max_bytes = max_bytes
        self.keep = keep
        self.flush_s = flush_s
        self.queue_limit = queue_limit
        self.dropped = 0
        self.thread_cpu_s = 0.0  # the writer thread's CPU time, once closed (what recording costs besides put)
        self.path = self.directory / run_file_name(meta)
        self.current = self.path
        self._queue: deque[tuple[Any, ...]] = deque()
        self._wake = threading.Event()
        self._closing = False
        self._encoder = msgspec.msgpack.Encoder()
        self._connection = self._open(self.path)
        self._prune()
        self._thread = threading.Thread(target=self._drain_forever, name="recording", daemon=True)
        self._thread.start()

    # --- the caller's side: never blocks --------------------------------------------------
    def put(self, t: float, kind: RecordKind, key: str, data: msgspec.Struct | bytes) -> None:
        """Queue one record (`data`: the kind's struct, or it already encoded)."""
        if len(self._queue) >= self.queue_limit:
            self.dropped += 1
            return
        self._queue.append((t, kind, key, data))

    def update_meta(self, **fields: Any) -> None:
        """Set RunMeta fields, written with the next batch."""
        self._queue.append((_META, fields))

    def close(self, timeout: float = 10.0) -> None:
        """Write what is queued and the final meta, then close the file."""
        if self._closing:
            return
        self._closing = True
        self._wake.set()
        self._thread.join(timeout)
        if self._thread.is_alive():
            log.warning("recording %s: the writer did not finish within %.0f s; %d records not written",
                        self.current, timeout, len(self._queue))

    # --- the writer thread ----------------------------------------------------------------
    def _drain_forever(self) -> None:
        try:
            while True:
                self._wake.wait(self.flush_s)
                closing = self._closing
                self._write_batch(self._take())
                if closing and not self._queue:
                    break
            if self.dropped:
                self.meta.dropped = self.dropped
            with self._connection:
                self.write_meta(self._connection, self.meta)
            self._complete(self._connection)  # one self-contained file once it ends
        except (sqlite3.Error, OSError) as exc:  # a full disk must not take the controller down
            log.error("recording %s stopped: %s", self.current, exc)
        finally:
            self._connection.close()
            self.thread_cpu_s = time.thread_time()

    def _take(self) -> list[tuple[Any, ...]]:
        queue = self._queue
        return [queue.popleft() for _ in range(len(queue))]

    def _write_batch(self, batch: list[tuple[Any, ...]]) -> None:
        if not batch:
            return
        encode = self._encoder.encode
        rows = []
        meta_changed = False
        for item in batch:
            if item[0] is _META:
                for name, value in item[1].items():
                    setattr(self.meta, name, value)
                meta_changed = True
                continue
            t, kind, key, data = item
            rows.append((t, kind.value, key, data if isinstance(data, bytes) else encode(data)))
        connection = self._connection
        with connection:
            connection.executemany("INSERT INTO events (t, kind, key, data) VALUES (?, ?, ?, ?)", rows)
            if meta_changed:
                self.write_meta(connection, self.meta)
        if self._size() > self.max_bytes:
            self._rotate()

    def _size(self) -> int:
        pages = self._connection.execute("PRAGMA page_count").fetchone()[0]
        return int(pages) * int(self._connection.execute("PRAGMA page_size").fetchone()[0])

    @staticmethod
    def _complete(connection: sqlite3.Connection) -> None:
        connection.execute(KIND_KEY_INDEX)
        connection.execute("PRAGMA journal_mode=DELETE")  # one self-contained file once it ends

    def _rotate(self) -> None:
        self._complete(self._connection)
        self._connection.close()
        self.meta.part += 1
        self.current = self.directory / run_file_name(self.meta, self.meta.part)
        self._connection = self._open(self.current)
        self._prune()

    def _open(self, path: Path) -> sqlite3.Connection:
        connection = sqlite3.connect(path, check_same_thread=False, isolation_level=None)
        connection.execute("PRAGMA journal_mode=WAL")  # readers (timeline, runs) see committed batches
        connection.execute("PRAGMA synchronous=NORMAL")
        connection.executescript(DDL)
        connection.isolation_level = ""  # `with connection` opens and commits a transaction
        with connection:
            self.write_meta(connection, self.meta)
        return connection

    @staticmethod
    def write_meta(connection: sqlite3.Connection, meta: RunMeta) -> None:
        connection.executemany("INSERT OR REPLACE INTO run_meta (key, value) VALUES (?, ?)",
                               [(k, json.dumps(v)) for k, v in msgspec.to_builtins(meta).items()])

    def _prune(self) -> None:
        """Delete the oldest recordings beyond `keep` (never the file being written)."""
        files = sorted(self.directory.glob(f"*{SUFFIX}"), key=lambda p: (p.stat().st_mtime, p.name))
        excess = len(files) - self.keep
        for old in files:
            if excess <= 0:
                break
            if old == self.current:
                continue
            for suffix in ("", "-wal", "-shm"):
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(f"{old}{suffix}")
            log.info("recording: deleted %s (keep %d files)", old, self.keep)
            excess -= 1
