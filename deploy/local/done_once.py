"""Was every operation of a `hubctl up` run done exactly once? Read from the run's recordings.

Each controller start records into a file of its own, so a run whose controller was restarted has
several; read together in the order they began, they say what the controller did over the whole
run. An operation's finish counts once: finishing again without a recorded reset in between
(`finished -> initial`, the console's reset or an order's end) is a redone operation, the failure a
controller restart must never cause. A restarted controller restores the operation states it persisted
(a `restore` record); announcing an operation it restored as finished is no new finish. Restoring one
as initial that was counted finished is a reset: an order's end, which the order book commits with the
product's reset (controller/production/book.py), by a controller killed before it recorded the reset.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from common.model import OperationState
from controller.recording.reader import Record, list_runs, open_run
from controller.recording.schema import OperationRecord, RecordKind, RestoreRecord
from controller.recording.writer import recording_dir

from .recordings import recording_settings

OPERATION_PREFIX = "op."  # operation states among the persisted (restored) values
FINISHED, INITIAL = OperationState.FINISHED.value, OperationState.INITIAL.value


def run_recordings(config_path: str, station: str, started: float) -> list[Path]:
    """The recordings of `station` begun at or after `started` (wall clock), oldest first: one per controller
    start of the run."""
    directory = recording_dir(recording_settings(config_path).dir)
    return [r.path for r in list_runs(directory)
            if not r.problem and r.meta.started >= started and r.meta.station == station]


@dataclass
class DoneOnce:
    recordings: list[Path]
    finishes: dict[str, int] = field(default_factory=dict)  # operation -> finishes recorded
    resets: dict[str, int] = field(default_factory=dict)  # operation -> finished -> initial recorded
    # Finishes known only from a restarted controller's restored state: the killed controller's last records, not yet
    # handed to its recording's writer, died with it.
    restored_only: set[str] = field(default_factory=set)

    def redone(self) -> dict[str, int]:
        """Operations finished more often than reset plus once, with their finishes."""
        return {op: n for op, n in self.finishes.items() if n > self.resets.get(op, 0) + 1}

    def text(self) -> str:
        files = f"{len(self.recordings)} recording{'s' if len(self.recordings) != 1 else ''}"
        redone = self.redone()
        if redone:
            listed = ", ".join(f"{op} {n} times" for op, n in sorted(redone.items()))
            return f"REDONE, from {files}: {listed}"
        if not self.finishes:
            return f"from {files}: no operation finished"
        restored = (f" ({len(self.restored_only)} known from a restarted controller's restored state: "
                    f"{', '.join(sorted(self.restored_only))})") if self.restored_only else ""
        return f"from {files}: each of {len(self.finishes)} finished operations finished once{restored}"


def check_done_once(recordings: list[Path]) -> DoneOnce:
    result = DoneOnce(list(recordings))
    for path in recordings:
        with open_run(path) as run:
            count_finishes(run.events(kinds={RecordKind.OPERATION, RecordKind.RESTORE}), result)
    return result


def count_finishes(records: Iterable[Record], into: DoneOnce) -> None:
    """Add one controller's `operation` and `restore` records (one recording, in order) to `into`."""
    # What this controller knew: only what it restored, not what the one before it did (a controller that lost its
    # state and finished an operation again redid it).
    state: dict[str, str] = {}
    for record in records:
        data = record.data
        if isinstance(data, RestoreRecord):
            for key, value in data.values.items():
                if key.startswith(OPERATION_PREFIX):
                    op = key.removeprefix(OPERATION_PREFIX)
                    first_seen = op not in state  # this controller's start-up restore, not an order's values
                    state[op] = str(value)
                    finishes, resets = into.finishes.get(op, 0), into.resets.get(op, 0)
                    if state[op] == FINISHED and finishes == resets:
                        into.finishes[op] = finishes + 1
                        into.restored_only.add(op)
                    elif state[op] == INITIAL and first_seen and finishes > resets:
                        into.resets[op] = resets + 1
        elif isinstance(data, OperationRecord):
            op = record.key
            if data.after == FINISHED and state.get(op) != FINISHED:
                into.finishes[op] = into.finishes.get(op, 0) + 1
            elif data.before == FINISHED and data.after == INITIAL:
                into.resets[op] = into.resets.get(op, 0) + 1
            state[op] = data.after
