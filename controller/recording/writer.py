"""Writing a run recording without ever blocking the caller: the caller's thread appends, a process writes.

`RecordingWriter.put` encodes a record in place into a buffer (wire.RecordBuffer: one msgspec call, no
object kept) and `ingested` appends an ingested batch as the controller took it. Every `flush_s` (or
CHUNK_BYTES) the buffer goes to the writer process (writer_process.py) through a pipe written without
blocking. That process decides what of each batch is stored, encodes it and does all the SQLite work.

Why a process: with a writer thread, recording cost the controller more of its ingest capacity than the
writer thread and the hooks themselves counted (tests/bench/bench_recording.py, README: with every state
changing, 6-8 % against 4-4.6 % counted). The rest came from the records the controller kept for the
writer (per 100,000 states, 128 more young collections and a full one of 41 ms over the whole heap),
from switching to the writer thread and back, and from the per-state Python deciding what of a batch to
keep. None of those run in the controller's process now: its share is ~1.5 %.

If the writer process is slower than the records come (a disk that does not answer), what the pipe
cannot take waits here, up to `backlog_bytes`; further records are dropped and counted (`RunMeta.dropped`,
written at close, said in the log once): the controller never waits for the disk. `close()` hands
everything over, has the run's end written and waits for the process. A controller killed with kill -9
still leaves a readable recording: its writer process sees the pipe close, writes what it received and
leaves the outcome `running`.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import os
import select
import subprocess
import sys
import time
import uuid
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import msgspec

from common.model import Value
from controller.recording.schema import HubState, RecordKind, RunMeta
from controller.recording.store import open_file, prune, run_file_name
from controller.recording.wire import CLOSE, INGESTED, META, RecordBuffer, message
from controller.recording.writer_process import Settings

log = logging.getLogger("statehub.recording")

RECORDING_DIR_ENV = "STATEHUB_RECORDING_DIR"  # overrides [controller.recording] dir (the test suite sets it)
FLUSH_S = 0.25  # the buffer goes to the writer process at least this often
CHUNK_BYTES = 256 * 1024  # ... or once it holds this much
BACKLOG_BYTES = 64 * 1024 * 1024  # waiting for the writer process before new records are dropped
CLOSE_WAIT_S = 3.0  # at a stop: within the controller's exit bound (common/plumbing/lifecycle.py)
PIPE_BYTES = 1024 * 1024  # asked of the kernel for the pipe (Linux's default limit for a user)
# The writer process gets this process's sys.path, as multiprocessing's spawn does, without re-importing
# our __main__ (the controller's or hubctl's) as spawn would.
_BOOT = ("import json, sys; sys.path[:] = json.loads(sys.argv[1]); "
         "from controller.recording.writer_process import main; main()")


def recording_dir(configured: str) -> Path:
    """Where runs are recorded: `configured` ([controller.recording] dir) unless $STATEHUB_RECORDING_DIR says."""
    return Path(os.environ.get(RECORDING_DIR_ENV) or configured)


class RecordingWriter:
    """One run's recording in `directory`; `path` is its first part file. Called from one thread."""

    def __init__(self, directory: str | Path, meta: RunMeta, *, max_bytes: int, keep: int,
                 flush_s: float = FLUSH_S, backlog_bytes: int = BACKLOG_BYTES) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        if not meta.run:
            meta.run = uuid.uuid4().hex[:8]
        self.meta = meta
        self.flush_s = flush_s
        self.backlog_bytes = backlog_bytes
        self.dropped = 0
        self.process_cpu_s = 0.0  # the writer process's CPU time, once closed (what recording costs besides put)
        self.process_start_cpu_s = 0.0  # ... of which starting Python and importing
        self.path = self.directory / run_file_name(meta)
        open_file(self.path, meta).close()  # here, not in the process: a directory that cannot be written raises
        prune(self.directory, keep, self.path)
        settings = msgspec.json.encode(Settings(str(self.path), meta, max_bytes, keep)).decode()
        try:
            self._process = subprocess.Popen([sys.executable, "-c", _BOOT, json.dumps(sys.path), settings],
                                             stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        except OSError:
            self.path.unlink(missing_ok=True)
            raise
        assert self._process.stdin is not None
        self._pipe = self._process.stdin.fileno()
        os.set_blocking(self._pipe, False)
        with contextlib.suppress(OSError, AttributeError):  # a bigger pipe: fewer partial writes
            fcntl.fcntl(self._pipe, fcntl.F_SETPIPE_SZ, PIPE_BYTES)
        self._records = RecordBuffer()
        self._backlog: deque[list[Any]] = deque()  # [what is still to be written of a message, its records]
        self._waiting = 0  # bytes in the backlog
        self._due = time.monotonic() + flush_s
        self._gone = False  # the writer process ended: every record is dropped
        self._closed = False

    # --- the caller's side: never blocks --------------------------------------------------
    def put(self, t: float, kind: RecordKind | str, key: str, data: Any) -> None:
        """Append one record (`data`: the kind's struct)."""
        if self._waiting > self.backlog_bytes or self._gone:
            self._drop(1)
            return
        try:
            self._records.append((t, kind, key, data))
        except (TypeError, ValueError, OverflowError):  # a bug of ours must not stop the controller
            log.exception("recording %s: a %s record of %r cannot be encoded; dropped", self.path, kind, key)
            self.dropped += 1
            return
        if len(self._records) >= CHUNK_BYTES or time.monotonic() >= self._due:
            self.flush()

    def ingested(self, t: float, changed: dict[str, Value], hub_states: Sequence[HubState]) -> None:
        """An ingested batch as the controller took it: its changed values and every sample's hub state
        (schema.HubState); the writer process keeps what a `states` row holds."""
        self.put(t, INGESTED, "", (changed, hub_states))

    def update_meta(self, **fields: Any) -> None:
        """Set RunMeta fields, written after the records put before."""
        for name, value in fields.items():
            setattr(self.meta, name, value)
        self.flush()
        self._send(message(META, fields), 0)

    def flush(self) -> None:
        """Hand what is buffered to the writer process now (`put` does it every `flush_s`)."""
        self._due = time.monotonic() + self.flush_s
        records = self._records.count
        if records:
            self._send(self._records.take(), records)
        elif self._backlog:
            self._pump()

    def close(self, timeout: float = CLOSE_WAIT_S) -> None:
        """Hand over what is buffered and the run's end, and wait for the writer process to write them. A
        writer process still busy after `timeout` goes on by itself (it ignores SIGTERM; the end of its
        input tells it the run is over): the controller's exit is not held up beyond its own bound."""
        if self._closed:
            return
        self._closed = True
        deadline = time.monotonic() + timeout
        self.flush()
        self._send(message(CLOSE, {"dropped": self.dropped} if self.dropped else {}), 0)
        self._pump(deadline)
        unsent = sum(records for _, records in self._backlog)
        process = self._process
        assert process.stdin is not None and process.stdout is not None
        with contextlib.suppress(OSError):
            process.stdin.close()  # the end of its input: it stops reading
        try:
            process.wait(max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            log.warning("recording %s: the writer process did not finish within %.0f s (it goes on by itself); "
                        "%d records not handed to it", self.path, timeout, unsent)
            return
        report = process.stdout.read()
        process.stdout.close()
        with contextlib.suppress(ValueError):
            spent = json.loads(report or b"{}")
            self.process_cpu_s, self.process_start_cpu_s = spent.get("cpu_s", 0.0), spent.get("started_cpu_s", 0.0)
        if process.returncode != 0:
            log.error("recording %s: the writer process failed (exit status %s)", self.path, process.returncode)

    # --- handing over -----------------------------------------------------------------------
    def _send(self, data: bytes | bytearray, records: int) -> None:
        if self._gone:
            self._drop(records)
            return
        self._backlog.append([memoryview(data), records])
        self._waiting += len(data)
        self._pump()

    def _pump(self, deadline: float | None = None) -> None:
        """Write the backlog into the pipe, as much as it takes now (until `deadline`, if given)."""
        backlog = self._backlog
        while backlog:
            entry = backlog[0]
            view: memoryview = entry[0]
            try:
                written = os.write(self._pipe, view)
            except BlockingIOError:
                written = 0
            except OSError as exc:  # the process ended (BrokenPipeError)
                self._lost(exc)
                return
            self._waiting -= written
            if written == len(view):
                backlog.popleft()
                continue
            entry[0] = view[written:]
            remaining = 0.0 if deadline is None else deadline - time.monotonic()
            if remaining <= 0:
                return
            select.select([], [self._pipe], [], remaining)

    def _lost(self, error: OSError) -> None:
        self._gone = True
        lost = sum(records for _, records in self._backlog) + self._records.count
        self._records.take()
        self._backlog.clear()
        self._waiting = 0
        log.error("recording %s: its writer process ended (%s): every record from now on is dropped", self.path,
                  error)
        self._drop(lost)

    def _drop(self, records: int) -> None:
        if not self.dropped and records and not self._gone:
            log.warning("recording %s: the disk does not keep up; records are dropped (counted in the recording)",
                        self.path)
        self.dropped += records
