"""Reading run recordings (layout: schema.py). Stable API for timeline, `hubctl runs` and replay:

    list_runs(directory) -> list[RunInfo]   # one per run (its first part), oldest first; unreadable
                                            # files are skipped (RunInfo.problem says why instead)
    with open_run(path) as run:             # path: any part of the run; its parts are chained
        run.meta                            # RunMeta (schema.py): station, model, mode, outcome, counts...
        run.parts                           # the part files read, in order
        run.end_t                           # t of the last record (controller clock, s since start)
        for record in run.events(kinds={RecordKind.PLAN, "operation"}, since=10.0, until=20.0, key="nr"):
            record.t, record.kind, record.key, record.data   # data: the kind's struct (DATA_TYPES)

`events()` yields records in the order they were written (the order the controller acted in);
`since`/`until` bound `t` (inclusive), `kinds` and `key` filter. A stored `states` row (one ingested
batch) is yielded as its `state` records, one per resource. A recording being written may be
read at the same time (SQLite WAL): what is committed is seen.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, TypeVar

import msgspec

from controller.recording.schema import (
    DATA_TYPES,
    FORMAT,
    READABLE_FORMATS,
    SUFFIX,
    RecordData,
    RecordKind,
    RunMeta,
    expand_states,
)


class RecordingError(ValueError):
    """A file that is not a readable recording (names the file and why)."""


Data = TypeVar("Data")


@dataclass(frozen=True)
class Record:
    t: float
    kind: RecordKind
    key: str
    data: RecordData

    def data_as(self, data_type: type[Data]) -> Data:
        """The data as the struct its kind holds (`events(kinds=...)` chose the kind): a typed read."""
        if not isinstance(self.data, data_type):
            raise RecordingError(f"a {self.kind.value} record of {self.key!r} at t={self.t:.3f} holds a "
                                 f"{type(self.data).__name__}, not a {data_type.__name__}")
        return self.data


@dataclass(frozen=True)
class RunInfo:
    path: Path  # the run's first part (or the first one kept)
    meta: RunMeta
    parts: int  # files of the run found
    size_bytes: int  # of all its parts
    problem: str = ""  # set for a file that could not be read; meta is then empty


# Any: each kind decodes to its own struct (DATA_TYPES), which the kind, not the type, tells apart.
_DECODERS: dict[RecordKind, msgspec.msgpack.Decoder[Any]] = {
    kind: msgspec.msgpack.Decoder(data_type) for kind, data_type in DATA_TYPES.items()}


def _connect(path: Path) -> sqlite3.Connection:
    if not path.is_file():
        raise RecordingError(f"{path}: no such recording")
    connection = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        connection.execute("SELECT 1 FROM events LIMIT 1")
    except sqlite3.DatabaseError as exc:
        connection.close()
        raise RecordingError(f"{path}: not a run recording ({exc})") from None
    return connection


def read_meta(path: Path) -> RunMeta:
    connection = _connect(path)
    try:
        return _meta(connection, path)
    finally:
        connection.close()


def _meta(connection: sqlite3.Connection, path: Path) -> RunMeta:
    values = {key: json.loads(value) for key, value in connection.execute("SELECT key, value FROM run_meta")}
    try:
        meta = msgspec.convert(values, RunMeta)
    except msgspec.ValidationError as exc:
        raise RecordingError(f"{path}: run_meta: {exc}") from None
    if meta.format not in READABLE_FORMATS:
        raise RecordingError(f"{path}: recording format {meta.format}, this statehub reads formats "
                             f"{', '.join(map(str, READABLE_FORMATS))} (and writes {FORMAT})")
    return meta


def _parts_of(path: Path, meta: RunMeta) -> list[Path]:
    """The part files of `path`'s run in `path`'s directory, in order."""
    parts = []
    for candidate in sorted(path.parent.glob(f"*{SUFFIX}")):
        try:
            other = read_meta(candidate) if candidate != path else meta
        except RecordingError:
            continue
        if other.run == meta.run:
            parts.append((other.part, candidate))
    return [p for _, p in sorted(parts)]


class Run:
    """A recorded run, all its parts chained; close it (or use it as a context manager)."""

    def __init__(self, path: Path) -> None:
        meta = read_meta(path)
        self.parts = _parts_of(path, meta) if meta.run else [path]
        self._connections = [_connect(p) for p in self.parts]
        # The newest part's meta has the run's end (each part starts with a copy of the first's).
        self.meta = _meta(self._connections[-1], self.parts[-1])
        self.first_part = _meta(self._connections[0], self.parts[0]).part

    def events(self, kinds: Iterable[RecordKind | str] | None = None, since: float | None = None,
               until: float | None = None, key: str | None = None) -> Iterator[Record]:
        where: list[str] = []
        parameters: list[str | float] = []
        states = kinds is None
        if kinds is not None:
            chosen = {RecordKind(k) for k in kinds}
            states = RecordKind.STATE in chosen or RecordKind.STATES in chosen
            if states:
                chosen |= {RecordKind.STATE, RecordKind.STATES}
            where.append(f"kind IN ({', '.join('?' * len(chosen))})")
            parameters += [k.value for k in chosen]
        if since is not None:
            where.append("t >= ?")
            parameters.append(since)
        if until is not None:
            where.append("t <= ?")
            parameters.append(until)
        if key is not None:  # a `states` row's resources are in its data: filtered once expanded
            where.append("(key = ? OR kind = 'states')" if states else "key = ?")
            parameters.append(key)
        query = "SELECT t, kind, key, data FROM events" + (f" WHERE {' AND '.join(where)}" if where else "") \
            + " ORDER BY id"
        for path, connection in zip(self.parts, self._connections, strict=True):
            for t, kind, record_key, data in connection.execute(query, parameters):
                record_kind = RecordKind(kind)
                try:
                    decoded = _DECODERS[record_kind].decode(data)
                except msgspec.DecodeError as exc:
                    raise RecordingError(f"{path}: {kind} record of {record_key!r} at t={t:.3f}: {exc}") from None
                if record_kind is not RecordKind.STATES:
                    yield Record(t, record_kind, record_key, decoded)
                    continue
                for resource, state in expand_states(decoded):
                    if key is None or resource == key:
                        yield Record(t, RecordKind.STATE, resource, state)

    @property
    def end_t(self) -> float:
        last = self._connections[-1].execute("SELECT MAX(t) FROM events").fetchone()[0]
        return float(last) if last is not None else 0.0

    def close(self) -> None:
        for connection in self._connections:
            connection.close()
        self._connections = []

    def __enter__(self) -> Run:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        self.close()


def open_run(path: str | Path) -> Run:
    """The run recorded in `path` (any of its parts). Raises RecordingError."""
    return Run(Path(path))


def list_runs(directory: str | Path) -> list[RunInfo]:
    """The runs recorded in `directory`, oldest first: one RunInfo per run, for its first part kept."""
    directory = Path(directory)
    if not directory.is_dir():
        return []
    runs: dict[str, list[tuple[RunMeta, Path]]] = {}
    broken: list[RunInfo] = []
    for path in sorted(directory.glob(f"*{SUFFIX}")):
        try:
            meta = read_meta(path)
        except RecordingError as exc:
            broken.append(RunInfo(path, RunMeta(), 1, path.stat().st_size, str(exc)))
            continue
        runs.setdefault(meta.run or str(path), []).append((meta, path))
    infos = []
    for parts in runs.values():
        parts.sort(key=lambda part: part[0].part)
        last_meta = parts[-1][0]
        infos.append(RunInfo(parts[0][1], last_meta, len(parts), sum(p.stat().st_size for _, p in parts)))
    infos.sort(key=lambda info: info.meta.started)
    return infos + broken
