"""`hubctl runs [DIR]`: the recorded runs, newest first, each with its outcome."""

from __future__ import annotations

import time
from pathlib import Path

from controller.recording.reader import RunInfo, list_runs
from controller.recording.schema import RunOutcome

COLUMNS = ("started", "run", "mode", "outcome", "operations", "plans", "replans", "faults", "duration", "size", "file")
OUTCOMES = {RunOutcome.RUNNING: "running/killed"}  # a run whose controller was killed never wrote its end


def run_row(info: RunInfo) -> tuple[str, ...]:
    meta = info.meta
    if info.problem:
        return ("?", "?", "?", "unreadable", "", "", "", "", "", _size(info.size_bytes), f"{info.path}: {info.problem}")
    started = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(meta.started)) if meta.started else "?"
    parts = f" ({info.parts} parts)" if info.parts > 1 else ""
    return (started, meta.run, meta.mode, OUTCOMES.get(meta.outcome, meta.outcome),
            f"{meta.operations_done}/{meta.operations_total}", str(meta.plans), str(meta.replans), str(meta.faults),
            f"{meta.duration:.1f} s", _size(info.size_bytes), f"{info.path}{parts}")


def _size(size: int) -> str:
    return f"{size / 1e6:.1f} MB" if size >= 1e5 else f"{size / 1e3:.0f} kB"


def runs_table(directory: str | Path) -> list[str]:
    """The lines `hubctl runs` prints: a header, then a row per run, newest first (unreadable files last)."""
    infos = list_runs(directory)
    readable = sorted((i for i in infos if not i.problem), key=lambda i: i.meta.started, reverse=True)
    rows = [COLUMNS, *(run_row(i) for i in readable), *(run_row(i) for i in infos if i.problem)]
    widths = [max(len(row[c]) for row in rows) for c in range(len(COLUMNS) - 1)]
    return ["  ".join([*(cell.ljust(w) for cell, w in zip(row, widths, strict=False)), row[-1]]).rstrip()
            for row in rows]
