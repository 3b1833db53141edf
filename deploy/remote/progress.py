"""Numbered steps with their outcome and duration: `[3/10] create venv on pi-tool.local ... ok (4.1 s)`.

On a terminal the running step shows its elapsed seconds, so that a minute of pip on a
Raspberry Pi does not look like a hang.
"""

from __future__ import annotations

import asyncio
import contextlib
import sys
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import TextIO


class StepFailed(RuntimeError):
    """A step failed; `cause` says what and where."""

    def __init__(self, number: int, total: int, title: str, cause: BaseException) -> None:
        self.number, self.total, self.title, self.cause = number, total, title, cause
        super().__init__(f"step [{number}/{total}] {title}: {cause}")


@dataclass
class Note:
    """What a step reports next to its `ok`."""

    detail: str = ""


class Progress:
    def __init__(self, total: int, *, out: TextIO | None = None, dry_run: bool = False) -> None:
        self.total = total
        self.number = 0
        self.out = out or sys.stdout
        self.dry_run = dry_run

    def say(self, line: str) -> None:
        print(line, file=self.out, flush=True)

    def show_command(self, line: str) -> None:
        """A command a dry run would have run."""
        self.say(f"      {line}")

    @contextlib.asynccontextmanager
    async def step(self, title: str, *, always: bool = False) -> AsyncIterator[Note]:
        """One step. In a dry run it only shows its commands, unless `always` (a step that
        only reads local files, and that later steps need)."""
        self.number += 1
        head = f"[{self.number}/{self.total}] {title}"
        note = Note()
        if self.dry_run and not always:
            self.say(f"{head} (dry run)")
            yield note
            return
        tty = self.out.isatty()
        print(f"{head} ...", end="", file=self.out, flush=True)
        began = time.monotonic()
        ticker = asyncio.create_task(self._tick(head, began)) if tty else None
        try:
            yield note
        except BaseException as exc:
            self._end(head, began, tty, ticker, "FAILED")
            if isinstance(exc, Exception) and not isinstance(exc, StepFailed):
                raise StepFailed(self.number, self.total, title, exc) from exc
            raise
        self._end(head, began, tty, ticker, "ok" + (f" ({time.monotonic() - began:.1f} s)")
                  + (f": {note.detail}" if note.detail else ""))

    def _end(self, head: str, began: float, tty: bool, ticker: asyncio.Task[None] | None, outcome: str) -> None:
        if ticker is not None:
            ticker.cancel()
        if outcome == "FAILED":
            outcome = f"FAILED ({time.monotonic() - began:.1f} s)"
        prefix = f"\r\x1b[K{head} ... " if tty else " "  # \x1b[K: erase the ticker
        print(f"{prefix}{outcome}", file=self.out, flush=True)

    async def _tick(self, head: str, began: float) -> None:
        while True:
            await asyncio.sleep(1.0)
            print(f"\r{head} ... {time.monotonic() - began:.0f} s", end="", file=self.out, flush=True)
