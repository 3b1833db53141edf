"""The recording's writer process: reads the controller's messages (wire.py) from its stdin and stores them.

Started by RecordingWriter (writer.py) with the first part file already created. Each RECORDS message is
one transaction: its records as they came, each ingested batch as the `states` row StatesFilter makes
of it. A CLOSE message ends the run; the end of stdin without one means the controller is gone (killed):
what came is written and the outcome stays `running`. It ignores SIGINT and SIGTERM: a Ctrl-C to the
terminal's process group or a systemd stop reaches the controller too, which then closes the recording,
and this process must live until it has written the controller's last records.

On exit it prints its CPU time as JSON on stdout (`{"cpu_s": ..., "started_cpu_s": ...}`, the latter what
starting Python and importing took): what recording costs besides the controller's own share, for
tests/bench/bench_recording.py.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import sqlite3
import sys
import time
from pathlib import Path
from typing import BinaryIO

import msgspec

from controller.recording.schema import RecordKind, RunMeta, StatesFilter
from controller.recording.store import Row, RunFiles
from controller.recording.wire import (
    CLOSE,
    HEADER,
    INGESTED,
    META,
    RECORDS,
    decode_fields,
    decode_ingested,
    decode_records,
)

log = logging.getLogger("statehub.recording")


class Settings(msgspec.Struct, frozen=True):
    path: str  # the run's first part file, created by RecordingWriter
    meta: RunMeta
    max_bytes: int
    keep: int


def rows_of(payload: bytes, states: StatesFilter, encode: msgspec.msgpack.Encoder) -> list[Row]:
    rows: list[Row] = []
    for t, kind, key, data in decode_records(payload):
        if kind == INGESTED:
            changed, hub_states = decode_ingested(data)
            record = states.row(changed, hub_states)
            if record is not None:
                rows.append((t, RecordKind.STATES.value, key, encode.encode(record)))
        else:
            rows.append((t, kind, key, data))  # stored as it came: a view of the payload
    return rows


def _read(stream: BinaryIO, size: int) -> bytes | None:
    data = stream.read(size)
    return data if len(data) == size else None


def serve(stream: BinaryIO, settings: Settings) -> None:
    files = RunFiles(Path(settings.path), settings.meta, max_bytes=settings.max_bytes, keep=settings.keep)
    states = StatesFilter()
    encode = msgspec.msgpack.Encoder()
    try:
        while True:
            header = _read(stream, HEADER.size)
            kind, length = HEADER.unpack(header) if header is not None else (0, 0)
            payload = _read(stream, length) if header is not None else None
            if payload is None:  # the end of the pipe (or of a message cut short) without CLOSE
                log.warning("recording %s: the controller went away without closing it; what it sent is written",
                            files.current)
                break
            if kind == RECORDS:
                files.write(rows_of(payload, states, encode))
            elif kind in (META, CLOSE):
                files.update_meta(decode_fields(payload))
                if kind == CLOSE:
                    break
    finally:
        files.close()


def main() -> None:
    started_cpu_s = time.process_time()  # the interpreter and the imports: once per run
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="%(asctime)s recording-writer %(levelname)s %(message)s")
    settings = msgspec.json.decode(sys.argv[-1], type=Settings)
    try:
        serve(sys.stdin.buffer, settings)
    except (sqlite3.Error, OSError, msgspec.DecodeError) as exc:  # a full disk must not take the controller down
        log.error("recording %s stopped: %s", settings.path, exc)
        sys.exit(1)
    finally:
        with contextlib.suppress(OSError):  # the controller was killed: nobody reads it
            os.write(sys.stdout.fileno(),
                     json.dumps({"cpu_s": time.process_time(), "started_cpu_s": started_cpu_s}).encode())
