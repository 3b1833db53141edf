"""`hubctl replay RUN --save-test tests/replays/NAME`: a recorded run trimmed to what a replay reads.

Kept: the run's meta and every record the replay feeds or compares, with the states' measured values
only (a hub's status and mirror seq are the watchdog's inputs, whose verdicts are kept). Dropped:
liveliness and the service's own event-log notes. The file is an ordinary recording (.sqlite), so the
suite's tests/test_replays.py replays it like any other.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

import msgspec

from controller.recording.reader import Run
from controller.recording.schema import DDL, SUFFIX, RecordKind, StateRecord
from controller.recording.store import write_meta

from .replay import CORE_EVENTS

DROPPED = frozenset({RecordKind.LIVELINESS})


def save_test(run: Run, target: str | Path) -> Path:
    """Write the trimmed run to `target` (.sqlite added); returns the path written."""
    path = Path(target)
    if path.suffix != SUFFIX:
        path = path.with_name(path.name + SUFFIX)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.unlink(missing_ok=True)
    meta = msgspec.structs.replace(run.meta, part=1)
    encode = msgspec.msgpack.encode
    rows = []
    for record in run.events():
        if record.kind in DROPPED or (record.kind is RecordKind.EVENT and record.key not in CORE_EVENTS):
            continue
        data = record.data
        if isinstance(data, StateRecord):
            if not data.values:
                continue
            data = StateRecord(values=data.values)
        rows.append((record.t, record.kind.value, record.key, encode(data)))
    connection = sqlite3.connect(path, isolation_level=None)
    try:
        connection.executescript(DDL)
        connection.execute("BEGIN")
        write_meta(connection, meta)
        connection.executemany("INSERT INTO events (t, kind, key, data) VALUES (?, ?, ?, ?)", rows)
        connection.execute("COMMIT")
        # A replay reads it once, in order: the indexes would double its size for nothing.
        connection.executescript("DROP INDEX events_t; VACUUM")
    finally:
        connection.close()
    return path
